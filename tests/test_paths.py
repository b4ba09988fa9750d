"""Every path glsim builds stays inside the output directory, and one run writes it at a time:
what users did (an output pattern or a camera name climbing out with '..', two libraries into
one directory), each refused by name before anything is written (CPU backend, small scenes)."""
from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from _user_scene import snapshot, write_scene
from glsim.cli import main
from glsim.errors import SceneError
from glsim.io import outdir

GLSIM = [sys.executable, "-m", "glsim.cli"]
ESCAPE = "../../escape_{camera}_{step:04d}"


def _tree(root: Path) -> list[str]:
    """Every path under ``root`` (directories too), relative."""
    return sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))


def _spec(d: Path, vary: str) -> Path:
    """A library spec over the user's scene (``d/in/scene.toml``), step 0, with ``vary``."""
    write_scene(d / "in")
    spec = d / "spec.toml"
    spec.write_text(f'scene = "in/scene.toml"\nsteps = [0]\n[vary]\n{vary}\n')
    return spec


def _refused(tmp_path, capsys, argv, *named):
    """Run the CLI: exit 2, the message naming each of ``named``, no traceback, nothing written."""
    before = _tree(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert all(n in err for n in named) and "Traceback" not in err, err
    assert _tree(tmp_path) == before
    return err


# ---- names that would leave the output directory --------------------------------------------------

@pytest.mark.parametrize("pattern, culprit", [
    (ESCAPE, "has the part '..', which leaves the output directory"),
    ("/tmp/glsim_abs_{camera}_{step}.{ext}", "is an absolute path"),
    ("{camera}\\{step}.{ext}", "contains '\\\\'"),
    (".{camera}_{step}.{ext}", "has the hidden name"),
])
def test_an_output_pattern_leaving_the_directory_is_refused_by_render_and_library(tmp_path, capsys, pattern,
                                                                                  culprit):
    scene = write_scene(tmp_path / "in", extra=f"[output]\npattern = {json.dumps(pattern)}\n")
    named = ("output.pattern", repr(pattern), culprit, "give names relative to the output directory")
    _refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "sub" / "out1"), "-q"], *named)
    spec = _spec(tmp_path / "lib", f"output.pattern = [{json.dumps(pattern)}]")
    err = _refused(tmp_path, capsys, ["library", str(spec), "-o", str(tmp_path / "lib" / "out"), "-q"], *named)
    assert "variant v0000" in err and "(set by vary.output.pattern)" in err
    assert not Path("/tmp/glsim_abs_cam0_0.tif").exists()


@pytest.mark.parametrize("name, culprit", [
    ("../../esc", "contains '/'"),
    ("/tmp/glsim_esc", "contains '/'"),
    ("a\u0000b", "contains '\\x00'"),
    ("x" * 300, "is 300 characters long"),
    ("..", "starts with '.'"),
])
def test_a_camera_name_that_is_not_a_plain_file_name_is_refused(tmp_path, capsys, name, culprit):
    scene = write_scene(tmp_path / "in")
    scene.write_text(scene.read_text().replace('name = "cam0"', f"name = {json.dumps(name)}"))
    named = ("cameras[0].name", culprit, "cannot name files", "use 1–64 letters, digits, '_', '-' or '.'")
    _refused(tmp_path, capsys, ["render", str(scene), "-o", str(tmp_path / "sub" / "out1"), "-q"], *named)
    spec = _spec(tmp_path / "lib", f"cameras.0.name = [{json.dumps(name)}]")
    err = _refused(tmp_path, capsys, ["library", str(spec), "-o", str(tmp_path / "lib" / "out"), "-q"], *named)
    assert "(set by vary.cameras.0.name)" in err


def test_inside_resolves_each_name_against_the_output_directory(tmp_path):
    out = tmp_path / "out"
    assert outdir.inside(out, ["a.tif", "cam0/0001.tif"], "k") == [out / "a.tif", out / "cam0" / "0001.tif"]
    out.mkdir()
    os.symlink(tmp_path, out / "link")                   # a folder that leads out
    for rel in ("../a.tif", "a/../../b.tif", str(tmp_path / "a.tif"), "a/.."):
        with pytest.raises(SceneError, match=r"^k: .* not inside the output directory .* without '\.\.'"):
            outdir.inside(out, ["ok.tif", rel], "k")
    with pytest.raises(SceneError, match=rf"^{out / 'link'}: is a symbolic link to {tmp_path}, outside the output "
                                         r"directory .* — remove the link"):
        outdir.inside(out, ["ok.tif", "link/a.tif"], "k")            # the folder named, not the key


# ---- one run at a time --------------------------------------------------------------------------------

HOLD = """import sys, time
from glsim.io.outdir import locked
with locked(sys.argv[1]):
    print("locked", flush=True)
    time.sleep(120)
"""


@pytest.fixture
def holder():
    """``holder(dir)``: a live process holding ``dir``'s lock (stopped with SIGTERM at the end)."""
    procs = []

    def start(d: Path) -> subprocess.Popen:
        p = subprocess.Popen([sys.executable, "-c", HOLD, str(d)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
        procs.append(p)
        assert p.stdout.readline() == "locked\n"
        return p
    yield start
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait()


@pytest.mark.process
def test_a_second_run_into_a_directory_in_use_is_refused_naming_the_holder(tmp_path, capsys, holder):
    """The user's case: `glsim library A -o D &` then `glsim library C -o D --force` mixed the two."""
    scene = write_scene(tmp_path / "in")
    spec = _spec(tmp_path / "lib", "noise.sigma = [1.0]")
    d = tmp_path / "D"
    p = holder(d)
    before = snapshot(tmp_path)
    for argv in (["library", str(spec), "-o", str(d), "--force", "-q"], ["render", str(scene), "-o", str(d), "-q"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"{d}: another glsim run is writing here (pid {p.pid} on {socket.gethostname()}, started " in err
        assert f"kill {p.pid}" in err and "another directory (-o)" in err and "Traceback" not in err
    assert snapshot(tmp_path) == before
    p.send_signal(signal.SIGTERM)                        # SIGTERM releases the lock like Ctrl-C
    p.wait(30)
    assert not d.exists()                                # the lock file gone, and the folder it made


@pytest.mark.process
def test_a_lock_left_by_a_dead_run_is_taken_over(tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()
    spec = _spec(tmp_path / "lib", "noise.sigma = [1.0]")
    for argv, d in ((["render", str(tmp_path / "lib" / "in" / "scene.toml")], tmp_path / "R"),
                    (["library", str(spec), "--workers", "1"], tmp_path / "L")):
        d.mkdir()
        (d / outdir.LOCK).write_text(json.dumps({"pid": dead.pid, "host": socket.gethostname(),
                                                 "started": "2024-01-01 00:00:00", "command": "glsim library"}))
        t0 = time.time()
        r = subprocess.run(GLSIM + argv + ["-o", str(d), "-q"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        assert f"took over the lock of a glsim run that is no longer running (pid {dead.pid} on" in r.stderr
        assert not (d / outdir.LOCK).exists() and time.time() - t0 < 60
        assert "cam0_0000.tif" in {p.name for p in d.rglob("*.tif")}
