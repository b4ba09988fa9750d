"""Issue 9, outputs: what a new user did, and what the output directory holds afterwards.

Nothing is written before the whole scene and every input it names is read and checked; a
directory holding another render is refused (``--force`` replaces it) and one holding the same
scene is resumed; an image and its truth appear together or not at all; a reference image that
does not cover the specimen is reported with the numbers."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
import tifffile

from _user_scene import snapshot, write_scene
from glsim.cli import main
from glsim.errors import RenderWarning, SceneError
from glsim.io import atomic
from glsim.io import images as io
from glsim.scene import load_scene
from glsim.workflows.sequence import write_sequence


def _render(scene_file, out, *args):
    return main(["render", str(scene_file), "-o", str(out), "-q", *args])


# --- nothing is written before every input is read and checked ------------------------------------

def _bad_point_data(d):
    return write_scene(d, point_data=("u1", "U2")), "has no point-data array 'U2'"


def _bad_csv(d):
    write_scene(d)
    (d / "u1.csv").write_text("label;ux;uy;uz\n101;0;0;0\n102;zero;0;0\n")
    path = d / "scene.toml"
    path.write_text(path.read_text().replace('point_data = ["u1", "u2"]', 'csv = ["u1.csv"]'))
    return path, "u1.csv:3: '102;zero;0;0' is not numeric"


def _bad_reference(d):
    d.mkdir(parents=True)
    (d / "ref.png").write_text("not an image")
    return write_scene(d, extra="[speckle]\nimage = 'ref.png'\nmm_per_px = 0.1\n"), "cannot read image"


def _nan_displacement(d):
    from _user_scene import write_mesh
    d.mkdir(parents=True)
    arrays = write_mesh(d / "plate.vtu")
    arrays["u2"][[3, 7]] = np.nan
    write_mesh(d / "plate.vtu", arrays)
    return write_scene(d, mesh=False), "'u2' (load step 2)"


def _bad_noise_table(d):
    path = write_scene(d, extra='[noise]\nmodel = "heteroscedastic"\nvariance_file = "v.csv"\n')
    (d / "v.csv").write_text("grey;variance\n0;abc\n")
    return path, "v.csv:2: expected two numbers"


@pytest.mark.parametrize("make", [_bad_point_data, _bad_csv, _bad_reference, _nan_displacement, _bad_noise_table],
                         ids=["point-data name", "csv line", "reference image", "NaN displacement", "noise table"])
def test_an_input_error_writes_nothing(tmp_path, capsys, make):
    """The user's case: an error found in the mesh, a CSV or the reference image left scene.json."""
    scene_file, culprit = make(tmp_path / "in")
    out = tmp_path / "out"
    assert _render(scene_file, out) == 2
    err = capsys.readouterr().err
    assert culprit in err and "Traceback" not in err
    assert not out.exists()                         # not even the directory
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    before = snapshot(out)
    assert _render(scene_file, out) == 2
    assert snapshot(out) == before                  # an existing directory holds nothing new


@pytest.mark.parametrize("steps, culprit", [("7", "steps: step 7 does not exist (the scene has steps 0…2)"),
                                            ("0,x", "--steps: cannot read '0,x'")])
def test_a_bad_steps_option_writes_nothing(tmp_path, capsys, steps, culprit):
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    assert _render(scene_file, out, "--steps", steps) == 2
    assert culprit in capsys.readouterr().err
    assert not out.exists()


# --- a directory holding a render -------------------------------------------------------------------

def test_a_directory_holding_another_render_is_refused(tmp_path, capsys):
    """The user's case: rendering into a directory with a render of another scene mixed the two."""
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    assert _render(scene_file, out, "--truth") == 0
    before = snapshot(out)
    capsys.readouterr()
    changed = write_scene(tmp_path / "in", mode="q4")
    assert _render(changed, out, "--truth") == 2
    err = capsys.readouterr().err
    assert f"{out}: holds a render of another scene (scene.json differs: render.mode is \"exact\" there, " \
           "\"q4\" now)" in err
    assert "--force" in err and "new directory" in err
    assert snapshot(out) == before                  # untouched


def test_force_replaces_the_render_and_keeps_other_files(tmp_path, capsys):
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    assert _render(scene_file, out, "--truth") == 0
    (out / "notes.txt").write_text("mine")
    (out / ".cam0_0002.tif.abc123.part.tif").write_bytes(b"left by a killed run")
    text = scene_file.read_text()
    renamed = tmp_path / "in" / "renamed.toml"          # another camera name: other file names
    renamed.write_text(text.replace('name = "cam0"', 'name = "left"'))
    assert _render(renamed, out, "--steps", "0-1", "--force") == 0
    assert "--force: removed 7 images and truth files" in capsys.readouterr().out
    assert sorted(snapshot(out)) == ["left_0000.tif", "left_0001.tif", "notes.txt", "render-manifest.jsonl",
                                     "scene.json"]
    assert load_scene(out / "scene.json").cameras[0].name == "left"


def test_a_non_empty_directory_without_a_render_is_refused(tmp_path, capsys):
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    out.mkdir()
    (out / "cam0_0000.tif").write_bytes(b"someone else's")
    assert _render(scene_file, out) == 2
    assert "is not empty (1 entries: cam0_0000.tif) and holds no scene.json of a render" in capsys.readouterr().err
    assert _render(scene_file, out, "--force") == 0
    assert io.read_image(out / "cam0_0000.tif").shape == (60, 80)


def test_the_same_scene_resumes(tmp_path, capsys):
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    assert _render(scene_file, out, "--steps", "0", "--truth") == 0
    first = (out / "cam0_0000.tif").stat().st_mtime_ns
    capsys.readouterr()
    assert _render(scene_file, out, "--truth") == 0
    text = capsys.readouterr().out
    assert "resumed: kept 1 image " in text and "wrote 2 images (2 truth files)" in text
    assert (out / "cam0_0000.tif").stat().st_mtime_ns == first
    # asking for truth in tiff now: the images without those truth files are rendered again
    assert _render(scene_file, out, "--truth", "--truth-format", "tiff") == 0
    assert "wrote 3 images" in capsys.readouterr().out
    assert _render(scene_file, out, "--truth", "--truth-format", "tiff") == 0   # and those resume in turn
    assert "resumed: kept 3 images" in capsys.readouterr().out


# --- an image and its truth: together or not at all -------------------------------------------------

def test_an_interrupt_between_image_and_truth_leaves_neither(tmp_path, monkeypatch, capsys):
    """The user's case: an interrupted render left cam1_0000.tif without its _truth.npz."""
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    real = io._image_file
    calls = []

    def interrupted(tmp, data, fmt):          # Ctrl-C while the second image is encoded
        calls.append(tmp)
        if len(calls) == 2:
            raise KeyboardInterrupt
        real(tmp, data, fmt)

    monkeypatch.setattr(io, "_image_file", interrupted)
    assert _render(scene_file, out, "--truth") == 130
    assert "run the same command again to resume" in capsys.readouterr().err
    assert sorted(snapshot(out)) == ["cam0_0000.tif", "cam0_0000_truth.npz", "render-manifest.jsonl", "scene.json"]
    monkeypatch.undo()
    assert _render(scene_file, out, "--truth") == 0
    assert "resumed: kept 1 image " in capsys.readouterr().out
    files = sorted(snapshot(out))
    assert files == ["cam0_0000.tif", "cam0_0000_truth.npz", "cam0_0001.tif", "cam0_0001_truth.npz",
                     "cam0_0002.tif", "cam0_0002_truth.npz", "render-manifest.jsonl", "scene.json"]


def test_truth_is_renamed_before_its_image(tmp_path, monkeypatch):
    """Killed between the renames: the truth may be there without its image, never the reverse."""
    real = os.replace
    names = []

    def replace(src, dst):
        names.append(os.path.basename(dst))
        if os.path.basename(dst) == "a.tif":
            raise KeyboardInterrupt
        real(src, dst)

    monkeypatch.setattr(atomic.os, "replace", replace)
    truth = {"mask": np.ones((2, 3), bool), "xi": np.zeros((2, 3))}
    with pytest.raises(KeyboardInterrupt):
        io.write_image_with_truth(tmp_path / "a.tif", np.zeros((2, 3)), 8, "tiff", truth, "tiff")
    assert names == ["a_truth_mask.tif", "a_truth_xi.tif", "a.tif"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_truth_mask.tif", "a_truth_xi.tif"]


def test_truth_tiff64_keeps_float64(tmp_path):
    scene = load_scene(write_scene(tmp_path / "in"))
    w = write_sequence(scene, tmp_path / "out", steps=[1], truth=True, truth_format="tiff64")
    npz = write_sequence(scene, tmp_path / "npz", steps=[1], truth=True)
    xd = tifffile.imread(tmp_path / "out" / "cam0_0001_truth_X_deformed.tif")
    ref = np.load(npz.truth[0])["X_deformed"]
    assert xd.dtype == np.float64 and np.array_equal(xd, ref, equal_nan=True)
    assert len(w.truth) == 7
    with pytest.raises(SceneError, match="truth_format: 'tif' is not one of"):
        write_sequence(scene, tmp_path / "x", truth=True, truth_format="tif")
    assert not (tmp_path / "x").exists()


# --- a reference image smaller than the specimen --------------------------------------------------

def _reference_scene(d, size_px):
    d.mkdir(parents=True)
    rng = np.random.default_rng(0)
    tifffile.imwrite(d / "ref.tif", (rng.random(size_px[::-1]) * 255).astype(np.uint8))
    return write_scene(d, extra="[speckle]\nimage = 'ref.tif'\nmm_per_px = 0.1\n")


@pytest.mark.process
def test_a_reference_image_smaller_than_the_specimen_is_refused(tmp_path, capsys):
    """The user's case: a 40 × 30 mm image on a 100 × 50 mm plate was silently cropped; then
    warned about; now refused before anything is written, naming the uncovered extent (issue 16)."""
    scene_file = _reference_scene(tmp_path / "in", (400, 300))
    run = subprocess.run([sys.executable, "-m", "glsim.cli", "render", str(scene_file), "-o", str(tmp_path / "out"),
                          "--steps", "0", "-q"], capture_output=True, text=True)
    assert run.returncode != 0 and not (tmp_path / "out").exists()
    line = next(x for x in run.stderr.splitlines() if "error" in x)
    assert line.startswith("glsim: error: speckle.image: the 400×300 px image (40×30 mm at 0.1 mm/px) would leave "
                           "part of the specimen without pattern, 76 % of its area: the image covers X -20…20, "
                           "Y -15…15 mm of it, the specimen spans X -50…50, Y -25…25 mm (in its own frame; ")
    assert "give an image of at least 1001×501 px at 0.1 mm/px, set speckle.mm_per_px ≥ 0.2503" in line
    assert "Traceback" not in run.stderr and ".py:" not in run.stderr     # no source line or location
    # the API refuses too; an image that covers the plate renders without a warning
    with pytest.raises(SceneError, match="76 % of its area"):
        write_sequence(load_scene(scene_file), tmp_path / "api", steps=[0])
    big = _reference_scene(tmp_path / "big", (1010, 510))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RenderWarning)
        write_sequence(load_scene(big), tmp_path / "ok", steps=[0])


def test_a_render_directory_of_an_earlier_release_resumes(tmp_path, capsys):
    """scene.json of a scene without the tables added since (sensor, psf, vignetting, exposure)
    is what the first release wrote: those tables are left out while absent, not written as null."""
    scene_file = write_scene(tmp_path / "in")
    out = tmp_path / "out"
    assert _render(scene_file, out, "--steps", "0") == 0
    written = json.loads((out / "scene.json").read_text())
    assert not {"sensor", "psf", "vignetting", "exposure"} & set(written)
    assert {"lighting", "optics", "noise"} <= set(written)        # the first release's optional tables, as then
    capsys.readouterr()
    assert _render(scene_file, out, "--steps", "0") == 0 and "resumed: kept 1 image " in capsys.readouterr().out
