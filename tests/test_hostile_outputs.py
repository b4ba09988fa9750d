"""Hostile output directories and arguments: a planted lock, link, directory or FIFO, files
that are not what the render wrote, colliding or giant output patterns, bad --steps, an -o that
cannot be made, a full disk. Each is refused by name with exit status 2 before anything is
written (no directory made, nothing outside -o touched), or — a resume — trusts only the bytes
its manifest recorded and removes only its own temporaries. CPU backend, small plates."""
from __future__ import annotations

import errno
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from _hostile import main_under_cap

from glsim.cli import main
from glsim.io import images as io
from glsim.io import outdir, rendermanifest
from glsim.scene import load_scene
from glsim.workflows.sequence import write_sequence

GLSIM = [sys.executable, "-m", "glsim.cli"]
CAMERA = '[[cameras]]\nname = "{name}"\nsize = [64, 48]\nfx = 300.0\nfy = 300.0\ncx = 31.5\ncy = 23.5\n'


def scene_file(d: Path, steps: int = 1, cameras=("cam0",), pattern: str | None = None, name: str = "s.toml",
               extra: str = "") -> Path:
    """A 40 × 30 mm plate seen by ``cameras``, ``steps`` translated load steps after step 0;
    ``extra``: more TOML tables."""
    moves = ", ".join(f"[{0.01 * k}, 0.0, 0.0]" for k in range(1, steps + 1))
    text = "".join(CAMERA.format(name=c) for c in cameras)
    text += (f"[specimen.plate]\nwidth = 40.0\nheight = 30.0\ntranslations = [{moves}]\n"
             "[specimen.pose]\nt = [0.0, 0.0, 300.0]\n[speckle]\ndot_diameter_px = 4.0\n[render]\nbackend = \"cpu\"\n")
    if pattern is not None:
        text += f"[output]\npattern = {json.dumps(pattern)}\n"
    text += extra
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_text(text)
    return d / name


def tree(root: Path) -> dict:
    """Every path under ``root`` (links not followed): its bytes, link target or kind."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        out[rel] = ("link", os.readlink(p)) if p.is_symlink() else p.read_bytes() if p.is_file() else "dir"
    return out


def render(scene: Path, out: Path, *extra) -> int:
    return main(["render", str(scene), "-o", str(out), "-q", *extra])


def refused(tmp_path, capsys, argv, *named) -> str:
    """Run the CLI: exit 2, every one of ``named`` in the message, no traceback, nothing written."""
    before = tree(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert all(n in err for n in named) and "Traceback" not in err and " — " in err, err
    assert tree(tmp_path) == before
    return err


# ---- a planted lock ------------------------------------------------------------------------------------

def _library_spec(d: Path) -> Path:
    scene_file(d, name="base.toml")
    (d / "spec.toml").write_text('scene = "base.toml"\nseed = 1\ncameras = ["cam0"]\nsteps = [0]\n'
                                 '[vary]\n"noise.sigma" = [0.0]\n')
    return d / "spec.toml"


@pytest.mark.parametrize("command", ["render", "library"])
@pytest.mark.parametrize("plant, what", [
    (lambda lock, victim: os.symlink(victim, lock), "is a symbolic link"),
    (lambda lock, victim: os.symlink(victim.with_name("absent"), lock), "is a symbolic link"),   # dangling
    (lambda lock, victim: lock.mkdir(), "is a directory"),
    (lambda lock, victim: os.mkfifo(lock), "is a FIFO"),
    (lambda lock, victim: os.link(victim, lock), "is a file with 2 names (hard links)"),
], ids=["link", "dangling link", "directory", "FIFO", "hard link"])
def test_a_planted_lock_is_refused_by_name_and_nothing_outside_is_written(tmp_path, capsys, command, plant, what):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    out = tmp_path / "out"
    out.mkdir()
    plant(out / outdir.LOCK, victim)
    source = scene_file(tmp_path / "in") if command == "render" else _library_spec(tmp_path / "in")
    err = refused(tmp_path, capsys, [command, str(source), "-o", str(out), "-q"], f"{out / outdir.LOCK}: {what}",
                  "not a file glsim wrote", "remove it")
    assert victim.read_text() == "precious" and not (tmp_path / "absent").exists()
    assert "IsADirectoryError" not in err


def test_a_running_process_named_in_a_free_lock_is_called_running(tmp_path, monkeypatch):
    """The kernel's lock is free, so the run goes on; but a recorded pid that runs (PID 1) or that
    glsim may not signal (EPERM) is not called 'no longer running'."""
    scene = load_scene(scene_file(tmp_path / "in"))
    for pid, kill in ((1, os.kill), (4242, lambda pid, sig: (_ for _ in ()).throw(PermissionError(errno.EPERM, "x")))):
        out = tmp_path / f"out{pid}"
        out.mkdir()
        (out / outdir.LOCK).write_text(json.dumps({"pid": pid, "host": socket.gethostname(), "started": "x",
                                                   "command": "glsim render"}))
        monkeypatch.setattr(outdir.os, "kill", kill)
        with pytest.warns(UserWarning, match=rf"running but does not hold the lock \(pid {pid} on") as seen:
            write_sequence(scene, out, steps=[0])
        assert not any("no longer running" in str(w.message) for w in seen)
        assert (out / "cam0_0000.tif").is_file() and not (out / outdir.LOCK).exists()


# ---- --steps -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("steps, culprit", [
    ("1-0", "--steps: the range 1-0 in '1-0' runs backwards — write it first-last: 0-1"),
    ("0-", "--steps: the range '0-' in '0-' has no last step"),
    ("0-1,1", "--steps: '0-1,1' asks for step 1 twice"),
    ("1,1", "--steps: '1,1' asks for step 1 twice"),
])
def test_bad_steps_are_refused_before_anything_is_written(tmp_path, capsys, steps, culprit):
    scene = scene_file(tmp_path / "in")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "out"), "-q", "--steps", steps], culprit)


def test_the_api_refuses_a_step_or_camera_asked_twice(tmp_path):
    scene = load_scene(scene_file(tmp_path / "in"))
    with pytest.raises(Exception, match="^steps: step 1 is asked for twice"):
        write_sequence(scene, tmp_path / "a", steps=[1, 1])
    with pytest.raises(Exception, match="^cameras: camera cam0 is asked for twice"):
        write_sequence(scene, tmp_path / "b", cameras=[0, "cam0"])
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


# ---- output.pattern ------------------------------------------------------------------------------------

def test_a_pattern_that_merges_real_steps_is_refused_naming_both(tmp_path, capsys):
    """With steps 0–12, {step:.0e} gives steps 10, 11 and 12 one name (cam0/cam1 × 0/1 do not show it)."""
    scene = scene_file(tmp_path / "in", steps=12, pattern="{camera}_{step:.0e}.{ext}")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "out"), "-q"],
            "output.pattern: '{camera}_{step:.0e}.{ext}' gives the image of camera cam0 at step 10 and the image of "
            "camera cam0 at step 11 the same file name 'cam0_1e+01.tif'", "include both {camera} and {step} in full")


def test_a_pattern_that_merges_real_camera_names_is_refused_naming_both(tmp_path, capsys):
    scene = scene_file(tmp_path / "in", cameras=("left_a", "left_b"), pattern="{camera:.4}_{step}.{ext}")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "out"), "-q"],
            "gives the image of camera left_a at step 0 and the image of camera left_b at step 0 the same file name "
            "'left_0.tif'")


def test_a_pattern_naming_glsims_own_file_is_refused(tmp_path, capsys):
    """Step 15 in hex makes the image name the flat field glsim writes beside it."""
    scene = scene_file(tmp_path / "in", steps=15, pattern="{camera}_{step:x}latfield.{ext}",
                       extra="[vignetting]\nnatural = true\nflat_field = true\n")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "out"), "-q"],
            "output.pattern: '{camera}_{step:x}latfield.{ext}' gives the image of camera cam0 at step 15 and "
            "cam0_flatfield.tif (glsim's own) the same file name 'cam0_flatfield.tif'")


@pytest.mark.parametrize("pattern, culprit", [
    ("{step:2000000000}", "asks for 2000000000 characters in {step:2000000000}, more than a file name holds"),
    ("{camera}_{step:.300f}.{ext}", "asks for 300 characters in {step:.300f}"),
    ("{step[0]}_{camera}.{ext}", "has the field {step[0]}"),
    ("{camera.__class__}_{step}.{ext}", "has the field {camera.__class__}"),
    ("{camera}_{step:{ext}}.{ext}", "nests a field in the format of {step:{ext}}"),
])
def test_a_pattern_is_bounded_before_it_is_formatted(tmp_path, capsys, pattern, culprit):
    scene = scene_file(tmp_path / "in", pattern=pattern)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "out"), "-q"], "output.pattern: ", culprit)


@pytest.mark.process
def test_a_giant_format_width_is_refused_under_a_500_MB_address_space_limit(tmp_path):
    argv = [["render", str(scene_file(tmp_path / f"in{i}", pattern=p)), "-o", str(tmp_path / f"out{i}"), "-q"]
            for i, p in enumerate(["{step:2000000000}", "{camera}_{step:.2000000000f}.{ext}",
                                   "{camera:>" + "9" * 5000 + "}{step}"])]
    results = main_under_cap(argv, timeout=120)
    for rc, err in results:
        assert rc == 2 and "output.pattern: " in err and "more than a file name holds (255 bytes)" in err, err
    assert not any((tmp_path / f"out{i}").exists() for i in range(3))


# ---- what is planted in a render's directory -----------------------------------------------------------

def test_a_symlinked_sub_folder_is_refused_naming_the_folder(tmp_path, capsys):
    scene = scene_file(tmp_path / "in", pattern="{camera}/{step:04d}.{ext}")
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    assert render(scene, out, "--steps", "0") == 0
    elsewhere.mkdir()
    (out / "cam0" / "0000.tif").rename(elsewhere / "0000.tif")
    (out / "cam0").rmdir()
    os.symlink(elsewhere, out / "cam0")
    err = refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"],
                  f"{out / 'cam0'}: is a symbolic link to {elsewhere}, outside the output directory", "remove the link")
    assert not err.startswith("glsim: error: output.pattern")


@pytest.mark.parametrize("plant, what", [
    (lambda p, victim: os.symlink(victim, p), "is a symbolic link"),
    (lambda p, victim: p.mkdir(), "is a directory"),
    (lambda p, victim: os.mkfifo(p), "is a FIFO (named pipe)"),
], ids=["link", "directory", "FIFO"])
def test_something_planted_where_an_image_goes_is_refused_by_name(tmp_path, capsys, plant, what):
    scene = scene_file(tmp_path / "in")
    out, victim = tmp_path / "out", tmp_path / "victim.tif"
    assert render(scene, out, "--steps", "0") == 0
    victim.write_bytes(b"precious")
    plant(out / "cam0_0001.tif", victim)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"],
            f"{out / 'cam0_0001.tif'}: {what}, where glsim writes the image of camera cam0 at step 1")
    assert victim.read_bytes() == b"precious"


@pytest.mark.parametrize("plant, what", [
    (lambda p: os.symlink("/dev/zero", p), "is a symbolic link"),
    (lambda p: p.mkdir(), "is a directory"),
], ids=["link", "directory"])
def test_a_planted_manifest_is_refused_by_name(tmp_path, capsys, plant, what):
    scene = scene_file(tmp_path / "in")
    out = tmp_path / "out"
    assert render(scene, out) == 0
    (out / rendermanifest.NAME).unlink()
    plant(out / rendermanifest.NAME)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"], f"{out / rendermanifest.NAME}: {what}")


def test_a_scene_json_planted_as_a_link_is_not_read(tmp_path, capsys):
    scene = scene_file(tmp_path / "in")
    out = tmp_path / "out"
    out.mkdir()
    os.symlink("/dev/zero", out / "scene.json")              # read, it would never end
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"],
            f"{out}: holds a scene.json that is not glsim's")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q", "--force"],
            f"{out / 'scene.json'}: is a symbolic link, where glsim writes scene.json")


# ---- resume trusts only what its manifest recorded ---------------------------------------------------

def test_resume_renders_again_every_file_that_does_not_match_the_manifest(tmp_path, capsys):
    """A 100-byte image, a 0-byte image and a truth file of "junk" were kept before; now each is
    rendered again (and said so), the result byte for byte a fresh render's."""
    scene = scene_file(tmp_path / "in", steps=3)
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    assert render(scene, fresh, "--truth") == 0
    assert render(scene, out, "--truth") == 0
    (out / "cam0_0000.tif").write_bytes((out / "cam0_0000.tif").read_bytes()[:100])
    (out / "cam0_0001.tif").write_bytes(b"")
    (out / "cam0_0002_truth.npz").write_bytes(b"junk")
    capsys.readouterr()
    assert render(scene, out, "--truth") == 0
    text = capsys.readouterr().out
    assert "resumed: kept 1 image" in text and "resumed: rendered 3 images again whose files there did not match " \
           "render-manifest.jsonl (cam0_0000.tif: 100 bytes, 3,328 recorded; cam0_0001.tif: 0 bytes" in text
    assert "cam0_0002_truth.npz: 4 bytes" in text
    same = lambda d: {k: v for k, v in tree(d).items() if k != rendermanifest.NAME}   # noqa: E731
    assert same(out) == same(fresh)


def test_resume_renders_again_a_file_edited_to_the_same_size(tmp_path, capsys):
    scene = scene_file(tmp_path / "in")
    out = tmp_path / "out"
    assert render(scene, out) == 0
    data = bytearray((out / "cam0_0001.tif").read_bytes())
    good = bytes(data)
    data[-1] ^= 0xFF
    (out / "cam0_0001.tif").write_bytes(bytes(data))
    capsys.readouterr()
    assert render(scene, out) == 0
    assert "cam0_0001.tif: its SHA-256 is not the one recorded" in capsys.readouterr().out
    assert (out / "cam0_0001.tif").read_bytes() == good


def test_resume_without_a_readable_manifest_renders_everything_again(tmp_path, capsys):
    """An earlier release's render (no manifest) or a manifest of garbage: no file is trusted."""
    scene = scene_file(tmp_path / "in")
    out = tmp_path / "out"
    assert render(scene, out) == 0
    garbage = b"\xff\xfe{not json\n" + b"x" * 10000 + b"\n[1, 2]\n"
    for damage in (lambda p: p.unlink(), lambda p: p.write_bytes(garbage)):
        damage(out / rendermanifest.NAME)
        capsys.readouterr()
        assert render(scene, out) == 0
        text = capsys.readouterr().out
        assert "resumed: rendered 2 images again" in text and "cam0_0000.tif: not in render-manifest.jsonl" in text
        assert render(scene, out) == 0 and "resumed: kept 2 images" in capsys.readouterr().out


KILLED = """import os, signal, sys
from glsim.io import images
real = images._image_file
def killed(tmp, data, fmt):                 # SIGKILL while the second image is being written
    real(tmp, data, fmt)
    if "0001" in str(tmp):
        os.kill(os.getpid(), signal.SIGKILL)
images._image_file = killed
from glsim.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.process
@pytest.mark.slow
def test_a_render_killed_mid_write_is_resumed_and_its_temporaries_swept(tmp_path):
    scene = scene_file(tmp_path / "in", steps=2)
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    argv = ["render", str(scene), "-o", str(out), "-q", "--truth"]
    r = subprocess.run([sys.executable, "-c", KILLED, *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == -signal.SIGKILL
    left = sorted(p.name for p in out.iterdir() if ".part" in p.name)
    assert len(left) == 2 and all(n.startswith((".cam0_0001.tif.", ".cam0_0001_truth.npz.")) for n in left)
    (out / ".notes.txt.abcdefgh.part.txt").write_text("not glsim's")   # a temporary of a name glsim does not write
    (out / "cam0_0001.tif.part").write_text("not glsim's either")
    r = subprocess.run(GLSIM + argv, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert "resumed: removed 2 temporary files an interrupted run left" in r.stdout
    assert "resumed: kept 1 image" in r.stdout
    assert sorted(p.name for p in out.iterdir() if "part" in p.name) == [".notes.txt.abcdefgh.part.txt",
                                                                         "cam0_0001.tif.part"]
    assert subprocess.run(GLSIM + ["render", str(scene), "-o", str(fresh), "-q", "--truth"]).returncode == 0
    for name in ("cam0_0000.tif", "cam0_0001.tif", "cam0_0002.tif", "cam0_0002_truth.npz", "scene.json"):
        assert (out / name).read_bytes() == (fresh / name).read_bytes(), name


# ---- -o that cannot be made or written -------------------------------------------------------------------

def test_an_output_under_a_file_is_refused_naming_it(tmp_path, capsys):
    scene = scene_file(tmp_path / "in")
    (tmp_path / "afile").write_text("x")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "afile" / "a" / "b"), "-q"],
            f"{tmp_path / 'afile' / 'a' / 'b'}: {tmp_path / 'afile'} is a regular file, not a directory")
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "afile"), "-q"],
            f"{tmp_path / 'afile'}: is a regular file, not a directory")


def test_an_output_name_too_long_is_refused_and_no_folder_is_left(tmp_path, capsys):
    scene = scene_file(tmp_path / "in")
    out = tmp_path / "new" / "deeper" / ("x" * 300)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"],
            "cannot be made: the name is too long for the filesystem")
    assert not (tmp_path / "new").exists()


def test_a_read_only_output_is_refused_naming_it(tmp_path, capsys, monkeypatch):
    scene = scene_file(tmp_path / "in")

    def read_only(self, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(Path, "mkdir", read_only)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "out"), "-q"],
            f"{tmp_path / 'out'}: cannot be made: the filesystem is read-only", "give a directory you can write to")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only directory")
def test_a_directory_without_write_permission_is_refused_naming_it(tmp_path, capsys):
    scene = scene_file(tmp_path / "in")
    out = tmp_path / "out"
    out.mkdir(mode=0o555)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"], f"{out}: cannot be written")


def test_a_full_disk_while_rendering_is_named_and_resumes(tmp_path, capsys, monkeypatch):
    scene = scene_file(tmp_path / "in", steps=2)
    out = tmp_path / "out"
    real = io._image_file

    def full(tmp, data, fmt):
        if "0001" in str(tmp):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(tmp, data, fmt)

    monkeypatch.setattr(io, "_image_file", full)
    assert render(scene, out, "--truth") == 2
    err = capsys.readouterr().err
    assert f"glsim: error: {out / 'cam0_0001.tif'}: cannot be written (the disk is full) — free space, then run " \
           "the same command again to resume" in err and "Traceback" not in err
    assert not [p for p in out.iterdir() if ".part" in p.name]
    monkeypatch.undo()
    assert render(scene, out, "--truth") == 0 and "resumed: kept 1 image" in capsys.readouterr().out


@pytest.mark.process
@pytest.mark.slow
def test_a_file_size_limit_while_rendering_is_a_named_error(tmp_path):
    """A real OSError from the kernel (EFBIG under RLIMIT_FSIZE: Python ignores SIGXFSZ)."""
    scene = scene_file(tmp_path / "in")
    script = ("import resource, sys\nresource.setrlimit(resource.RLIMIT_FSIZE, (8000, 8000))\n"
              "from glsim.cli import main\nsys.exit(main(sys.argv[1:]))\n")
    r = subprocess.run([sys.executable, "-c", script, "render", str(scene), "-o", str(tmp_path / "out"), "-q",
                        "--truth"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert f"glsim: error: {tmp_path / 'out' / 'cam0_0000.tif'}: cannot be written (a file would exceed the size " \
           "this process may write (ulimit -f)) — " \
           "check that the output directory is writable, then run the same command again to resume" in r.stderr


# ---- demo's arguments -------------------------------------------------------------------------------------

@pytest.mark.parametrize("args, culprit", [
    (["--size", "0", "48"], "--size: must be two image sides of 1…16384 px, got 0 48"),
    (["--size", "64", "100000"], "--size: must be two image sides of 1…16384 px"),
    (["--n-steps", "0"], "--n-steps: must be 1…9999 load steps, got 0"),
    (["--steps", "2-1"], "--steps: the range 2-1"),
])
def test_demo_arguments_are_refused_by_flag_before_anything_is_written(tmp_path, capsys, args, culprit):
    refused(tmp_path, capsys, ["demo", "-o", str(tmp_path / "demo"), "-q", "--backend", "cpu", *args], culprit)


def test_resume_keeps_images_with_other_names_and_appends_to_no_other_file(tmp_path, capsys):
    """Images hard-linked into a backup (cp -al) are read, not refused; a manifest with another name
    is not appended to (it would write into that other file) but refused by name."""
    scene = scene_file(tmp_path / "in")
    out, backup = tmp_path / "out", tmp_path / "backup"
    assert render(scene, out) == 0
    backup.mkdir()
    for name in ("cam0_0000.tif", "cam0_0001.tif"):
        os.link(out / name, backup / name)
    capsys.readouterr()
    assert render(scene, out) == 0 and "resumed: kept 2 images" in capsys.readouterr().out
    os.link(out / rendermanifest.NAME, backup / rendermanifest.NAME)
    refused(tmp_path, capsys, ["render", str(scene), "-o", str(out), "-q"],
            f"{out / rendermanifest.NAME}: is a file with 2 names (hard links), not a file glsim wrote")
