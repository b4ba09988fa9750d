"""`glsim preview LIBRARY_DIR`: the calibration-library pager. Its drawn points against the
library's own ground truth (projected points from the pair JSON, not the detector's output),
paging by key events, the screenshot through the CLI, named errors, and the window under Xvfb."""
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from glsim.errors import SceneError
from glsim.workflows.calib import library as libmod
from glsim.workflows.calib import poses as posemod
from glsim.workflows.calib.targets import DotGrid
from glsim.workflows.preview.calibpager import GREEN, RED, LibraryPager, fit_box, to_frame

SIZE = (960, 540)


@pytest.fixture(scope="module")
def library(tmp_path_factory, gl_ctx):
    """Three pairs of the paper's rig at 1/4 scale, the target in the centre of the view."""
    out = tmp_path_factory.mktemp("pager") / "lib"
    libmod.write_library(libmod.paper_rig(0.25), DotGrid(), 3, out, seed=7, ctx=gl_ctx,
                         spec=posemod.PoseSpec(fov="centre"))
    return out


def _near(frame, uv, colour, radius):
    """Whether a pixel of ``colour`` (±40 per channel) lies within ``radius`` px of each uv."""
    H, W, _ = frame.shape
    hits = []
    for u, v in uv:
        x0, x1 = int(max(0, u - radius)), int(min(W, u + radius + 1))
        y0, y1 = int(max(0, v - radius)), int(min(H, v + radius + 1))
        patch = frame[y0:y1, x0:x1].astype(int)
        hits.append(bool((np.abs(patch - colour) <= 40).all(axis=-1).any()))
    return np.array(hits)


def test_points_are_drawn_where_the_truth_puts_them(library):
    """Every detected dot is ringed in green within 6 px (the ring's radius + 2) of its true
    projected centre in the frame; the tile shows the recorded image."""
    with LibraryPager(library, size=SIZE) as pg:
        frame = pg.frame()
        pair = pg.lib.pairs[0]
        for cam, box in zip(pg.lib.cameras, pg.layout()):
            truth = libmod.image_truth(pg.lib, pair, cam)
            x, y, w, h, s = fit_box((cam.size[1], cam.size[0]), box)
            uv = to_frame(truth["projected"], x, y, s)
            assert _near(frame, uv, GREEN, 6).mean() > 0.95
            assert frame[y + h // 2, x:x + w].std() > 0          # the image, not an empty tile
        found = [e[0] for e in pg.errors(0)]
        assert found == [81, 81]
        assert all(e[1] < 0.1 for e in pg.errors(0))           # detected vs true centroid, px


def test_a_missed_point_gets_a_red_cross_at_its_true_place(library):
    with LibraryPager(library, size=SIZE) as pg:
        points, why = pg.detection(0)
        lost = points[0].copy()
        lost[40] = np.nan
        pg._cache[0] = ([lost, points[1]], why)
        frame = pg.frame()
        cam, box = pg.lib.cameras[0], pg.layout()[0]
        x, y, w, h, s = fit_box((cam.size[1], cam.size[0]), box)
        uv = to_frame(libmod.image_truth(pg.lib, pg.lib.pairs[0], cam)["projected"][[40]], x, y, s)
        assert _near(frame, uv, RED, 3).all()
        assert pg.errors(0)[0][0] == 80


def test_keys_page_and_wrap(library):
    with LibraryPager(library, size=SIZE) as pg:
        pg.frame()
        assert not pg.needs_redraw
        seen = []
        for key in ("ArrowRight", "ArrowRight", "ArrowRight", "ArrowLeft", "Home", "End"):
            assert pg.handle_event({"type": "key_down", "key": key})      # each changes the page
            seen.append(pg.page)
            pg.frame()
        assert seen == [1, 2, 0, 2, 0, 2]
        pg.handle_event({"type": "key_down", "key": "q"})
        assert pg.quit_requested


@pytest.mark.process
def test_screenshot_through_the_cli_and_named_errors(library, tmp_path):
    import imageio.v3 as iio
    out = tmp_path / "page.png"
    r = subprocess.run([sys.executable, "-m", "glsim.cli", "preview", str(library), "--screenshot", str(out),
                        "--size", *map(str, SIZE), "--step", "1"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    with LibraryPager(library, size=SIZE) as pg:
        pg.go(1)
        assert np.array_equal(iio.imread(out), pg.frame())
    broken = tmp_path / "broken"
    shutil.copytree(library, broken)
    (broken / "pairs" / "0001.json").write_text("{")
    r = subprocess.run([sys.executable, "-m", "glsim.cli", "preview", str(broken), "--screenshot", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "Traceback" not in r.stderr and "0001.json" in r.stderr
    with pytest.raises(SceneError, match="0000_cam0"):
        (broken / "pairs" / "0001.json").write_text((library / "pairs" / "0001.json").read_text())
        (broken / "pairs" / "0000_cam0.tif").unlink()
        LibraryPager(broken).frame()


@pytest.mark.process
def test_window_pages_under_xvfb(library, preview_window):
    """A real window on a virtual X server: a real key press turns the page (the frame log says
    which pair is shown and how many points each camera found)."""
    with preview_window(str(library), "--size", *map(str, SIZE), "--log-frames") as (app, env):
        first = app.stdout.readline()
        assert "page=0 pair=0" in first and "cam0=81 cam1=81" in first, first + app.stderr.read()
        deadline = time.monotonic() + 30
        wid = ""
        while not wid and time.monotonic() < deadline:
            wid = subprocess.run(["xdotool", "search", "--name", "glsim preview"], env=env, capture_output=True,
                                 text=True).stdout.split()[:1]
            wid = wid[0] if wid else ""
        subprocess.run(["xdotool", "key", "--window", wid, "Right"], env=env, check=True)
        assert "page=1 pair=1" in app.stdout.readline()
        subprocess.run(["xdotool", "key", "--window", wid, "q"], env=env, capture_output=True)
        assert app.wait(30) == 0
