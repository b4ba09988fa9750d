"""End-to-end: the command line on small scenes, images re-read and checked; atomic writes;
the built wheel renders with its packaged shaders."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from glsim.io import images as io
from glsim.cli import main
from glsim.render import Renderer
from glsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


@pytest.mark.gl
def test_demo_writes_a_stereo_sequence(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "-o", str(out), "--size", "203", "154", "--n-steps", "1", "-q"]) == 0
    files = sorted(p.name for p in out.iterdir())
    assert files == ["cam0_0000.tif", "cam0_0001.tif", "cam1_0000.tif", "cam1_0001.tif", "render-manifest.jsonl",
                     "scene.json"]
    for name in files[:4]:
        img = io.read_image(out / name)
        assert img.shape == (154, 203) and img.dtype == np.uint8
        covered = img > 0
        assert 0.3 < covered.mean() < 0.9 and img[covered].std() > 40  # a speckled plate
    scene = json.loads((out / "scene.json").read_text())
    assert scene["render"]["mode"] == "exact" and len(scene["cameras"]) == 2
    assert "wrote 4 images" in capsys.readouterr().out


@pytest.mark.gl
def test_render_scene_file_with_truth_matches_api(tmp_path):
    scene_file = ROOT / "examples" / "plate_shift.toml"
    out = tmp_path / "out"
    assert main(["render", str(scene_file), "-o", str(out), "--backend", "gl", "--steps", "0-1", "--truth", "-q"]) == 0
    scene = load_scene(scene_file).replace(render={"backend": "gl"})
    with Renderer(scene) as r:
        res = r.render(0, 1, truth=True)
    cam = scene.cameras[0].name
    img = io.read_image(out / f"{cam}_0001.png")  # the example asks for PNG
    assert np.array_equal(img, io.quantize(res.image, scene.cameras[0].bit_depth))
    assert img.shape == (240, 320)
    truth = np.load(out / f"{cam}_0001_truth.npz")
    assert set(truth.files) == {"mask", "element", "xi", "eta", "ref_uv", "X_undeformed", "X_deformed"}
    assert np.array_equal(truth["mask"], res.truth.mask)
    tiff = tmp_path / "tiff"
    assert main(["render", str(scene_file), "-o", str(tiff), "--steps", "1", "--truth", "--truth-format", "tiff",
                 "-q"]) == 0
    ref_uv = io.read_image(tiff / f"{cam}_0001_truth_ref_uv.tif")
    assert ref_uv.dtype == np.float32 and ref_uv.shape == (240, 320, 2)
    m = res.truth.mask
    np.testing.assert_allclose(ref_uv[m], res.truth.ref_uv[m], atol=1e-4)  # float32 storage (CPU render here)
    assert np.array_equal(io.read_image(tiff / f"{cam}_0001_truth_mask.tif").astype(bool), m)


def test_bad_scene_gives_a_clear_message_not_a_traceback(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[[cameras]]\nsize = [64, 48]\nfx = -5.0\nfy = 100.0\ncx = 32.0\ncy = 24.0\n')
    assert main(["render", str(bad), "-o", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "cameras[0].fx" in err and "Traceback" not in err


@pytest.mark.gl
def test_info_names_the_renderer(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert "renderer" in out and "fp64" in out and "max_texture_size" in out
    assert "egl_devices" in out and "0: " in out      # every EGL device listed with its index
    # the arithmetic the exact mode gets, and the float64 / float32 throughput ratio behind it
    # (the same multiply-adds timed in both widths): a finite positive number, and the fp32
    # advice given exactly when it is below SLOW_FP64_RATE
    from glsim.backends.gl.context import SLOW_FP64_RATE

    line = next(x for x in out.splitlines() if x.startswith("exact_precision"))
    rate = float(next(x for x in out.splitlines() if x.startswith("fp64_rate")).split()[1])
    assert line.split()[1] in ("fp64", "fp64;") and math.isfinite(rate) and rate > 0.0
    assert ("precision = 'fp32' renders exact faster" in line) == (rate < SLOW_FP64_RATE)


@pytest.mark.parametrize("phi, why", [(90.0, "outside its field of view"), (200.0, r"the specimen lies behind it\)")])
def test_render_warns_when_a_camera_sees_none_of_the_specimen(tmp_path, phi, why):
    """Issue 29: a stereo angle that turns camera 1 away from the specimen wrote black images, exit 0."""
    from glsim.errors import RenderWarning

    scene = tmp_path / "away.toml"
    scene.write_text((ROOT / "examples" / "plate_shift.toml").read_text().replace("[specimen.plate]", f"""
[[cameras]]
name = "cam1"
size = [160, 120]
fx = 900.0
fy = 900.0
cx = 79.5
cy = 59.5
pose = {{stereo = {{Tx = -60.0, Ty = 0.0, Tz = 5.0, Theta = 0.0, Phi = {phi}, Psi = 0.0}}}}

[specimen.plate]"""))
    with pytest.warns(RenderWarning, match=r"camera cam1: sees none of the specimen \(.*" + why) as seen:
        assert main(["render", str(scene), "-o", str(tmp_path / "o"), "--steps", "0", "--backend", "cpu", "-q"]) == 0
    assert not any("cam0" in str(w.message) and "sees none" in str(w.message) for w in seen)


def test_info_says_why_a_driver_without_float64_gets_float32():
    from types import SimpleNamespace

    from glsim.backends.gl.context import info

    ctx = SimpleNamespace(extensions=set(), error="GL_NO_ERROR", info={"GL_VENDOR": "v", "GL_RENDERER": "r", "GL_VERSION": "4.5",
                                                  "GL_MAX_TEXTURE_SIZE": 16384, "GL_SHADING_LANGUAGE_VERSION": "4.50"})
    out = info(ctx)
    assert out["fp64"] is False and "fp64_rate" not in out
    assert out["exact_precision"].startswith("fp32") and "GL_ARB_gpu_shader_fp64" in out["exact_precision"]


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    import tifffile

    def fail(path, data, **kw):
        Path(path).write_bytes(b"half an image")
        raise KeyboardInterrupt

    monkeypatch.setattr(tifffile, "imwrite", fail)
    target = tmp_path / "img.tif"
    with pytest.raises(KeyboardInterrupt):
        io.write_image(target, np.zeros((4, 4)), 8)
    assert list(tmp_path.iterdir()) == []


def test_quantize_rounds_and_clips():
    q = io.quantize(np.array([-0.1, 0.0, 0.5 / 255, 1.5 / 255, 1.0, 2.0]), 8)
    assert q.tolist() == [0, 0, 0, 2, 255, 255]  # round half to even
    assert io.quantize(np.array([1.0]), 12).tolist() == [4095]


@pytest.mark.process
@pytest.mark.gl
def test_wheel_ships_shaders_and_renders(tmp_path):
    """A non-editable install of the built wheel renders with its packaged GLSL."""
    wheel_dir = tmp_path / "dist"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheel_dir), str(ROOT)],
                   check=True)
    wheel, = wheel_dir.glob("glsim-*.whl")
    import zipfile
    names = zipfile.ZipFile(wheel).namelist()
    assert "glsim/shaders/single.frag" in names and "glsim/shaders/camera.glsl" in names
    packages = {str(f.relative_to(ROOT)) for f in (ROOT / "glsim").rglob("__init__.py")}
    assert packages <= set(names), f"add {sorted(packages - set(names))} to pyproject's packages"
    assert not [n for n in names if n.startswith("tools/")], "the repository's tools/ is not part of the wheel"
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(wheel)],
                   check=True)
    code = ("import glsim, numpy as np; from glsim.scene import bulge_scene; from glsim.render import render;"
            "r = render(bulge_scene(size=(101, 77), steps=1), 0, 1, backend='gl');"
            "print(glsim.__file__); assert r.image.max() > 0")
    env = dict(os.environ, PYTHONPATH=str(target))
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().startswith(str(target))


@pytest.mark.gl
def test_demo_effects_variant(tmp_path, capsys):
    out = tmp_path / "fx"
    assert main(["demo", "--effects", "-o", str(out), "--size", "203", "154", "--n-steps", "1", "-q"]) == 0
    scene = json.loads((out / "scene.json").read_text())
    assert scene["lighting"]["lights"] and scene["optics"]["f_number"] == 2.0 and scene["noise"]["sigma"] == 2.0
    plain = tmp_path / "plain"
    assert main(["demo", "-o", str(plain), "--size", "203", "154", "--n-steps", "1", "-q"]) == 0
    a, b = io.read_image(out / "cam0_0001.tif"), io.read_image(plain / "cam0_0001.tif")
    assert a.shape == b.shape and not np.array_equal(a, b)
    out_text = capsys.readouterr().out
    assert "spotlight" in out_text and "saturated (clipped) pixels" in out_text  # noise clips the dark background


def test_written_scene_json_re_renders_the_same_images(tmp_path):
    """scene.json holds the resolved scene: rendering it again gives the same images bit for bit."""
    first, second = tmp_path / "a", tmp_path / "b"
    assert main(["render", str(ROOT / "examples" / "plate_shift.toml"), "-o", str(first), "--steps", "1", "-q"]) == 0
    assert main(["render", str(first / "scene.json"), "-o", str(second), "-q"]) == 0
    assert (first / "cam0_0001.png").read_bytes() == (second / "cam0_0001.png").read_bytes()
    assert load_scene(first / "scene.json") == load_scene(ROOT / "examples" / "plate_shift.toml")
