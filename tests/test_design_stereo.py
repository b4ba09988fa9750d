"""glsim design with stereo DIC (engine pyvale3d), without the engine: bad stereo specs refused by
key before anything runs, the stereo ROI (what camera 1 sees too), the truth against an imposed
rigid translation, the bias/noise maps and the noise floor against injected errors through a
stand-in engine, the exchange folder in verify/dic.py's format, and the rig in the cache key."""
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile

from glsim.io.calibfiles import pyvale_calibration
from glsim.scene import scene_from_dict
from glsim.scene.camera import rodrigues
from glsim.scene.locate import points_truth
from glsim.io.truth import mesh_geometry
from glsim.workflows.design import quick, run as design_run, stereo
from glsim.workflows.design.cli import main
from glsim.workflows.design.spec import check_design

from _design import BIAS, SPREAD, StandIn, pinhole, plate_rotation, plate_scene, stereo_plate, write_spec


# ---- refusals ---------------------------------------------------------------------------------------
ONE = {"dic": {"subset_size": [21]}}
BAD = [("mono", {**ONE, "engine": "pyvale3d"}, "engine: pyvale3d needs two cameras"),
       ("stereo", {**ONE, "engine": "pyvale3d", "rank": {"by": "p95_abs_error_px"}}, "rank.by: 'p95_abs_error_px' is a 2-D"),
       ("stereo", {**ONE, "engine": "pyvale3d", "rank": {"by": "mei_px2"}}, "rank.by: 'mei_px2' is a 2-D"),
       ("stereo", {**ONE, "engine": "pyvale3d", "rank": {"by": "p95_abs_V_mm"}}, "rank.by: 'p95_abs_V_mm' is not"),
       ("mono", {**ONE, "engine": "pyvale2d", "rank": {"by": "p95_abs_W_mm"}}, "rank.by: 'p95_abs_W_mm' is a stereo"),
       ("stereo", {**ONE, "engine": "pyvale3d", "camera": "cam0"}, "camera: engine pyvale3d measures a stereo pair"),
       ("stereo", {**ONE, "engine": "pyvale2d", "cameras": ["cam0", "cam1"]}, "cameras: the stereo pair is for"),
       ("stereo", {**ONE, "engine": "pyvale3d", "cameras": ["cam0"]}, "cameras: expected two camera"),
       ("stereo", {**ONE, "engine": "pyvale3d", "cameras": ["cam1", "cam1"]}, "cameras: ['cam1', 'cam1'] names one"),
       ("stereo", {**ONE, "engine": "pyvale3d", "cameras": ["cam0", "cam7"]}, "cameras: no camera named 'cam7'"),
       ("k4", {**ONE, "engine": "pyvale3d"}, "cameras.cam1.distortion"),
       ("stereo", {**ONE, "engine": "pyvale3d", "rank": {"by": "spatial_resolution_px"}}, "add a [resolution] table"),
       ("small", {**ONE, "engine": "pyvale3d", "resolution": {"periods_px": [32, 64]}}, "cameras.cam0.size"),
       ("stereo", {**ONE, "engine": "pyvale3d", "dic": {"subset_size": [301]}}, "dic.subset_size: 301 px is larger")]


@pytest.mark.parametrize("scene,top,key", BAD)
def test_bad_stereo_specs_are_refused_by_key_in_one_line_before_anything_is_written(tmp_path, capsys, scene, top, key):
    scenes = {"mono": plate_scene(), "stereo": stereo_plate(), "small": stereo_plate(size=(200, 200))}
    if scene == "k4":
        scenes[scene] = stereo_plate()
        scenes[scene]["cameras"][1]["distortion"] = {"k4": 0.01}
    spec = write_spec(tmp_path / "spec.toml", scenes[scene], **top)
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err, err
    assert err.count("\n") == 1 and " — " in err        # one line: the key, the culprit — the fix
    assert not out.exists()


def test_stereo_design_defaults_to_the_first_two_cameras_and_a_stereo_criterion(tmp_path):
    d = check_design({"engine": "pyvale3d", "dic": {"subset_size": [21]}, "scene": stereo_plate()}, tmp_path)
    assert d.cameras == ("cam0", "cam1") and d.camera == "cam0" and d.rank_by == "p95_abs_error_mm" and d.stereo
    d = check_design({"engine": "pyvale3d", "cameras": [1, 0], "dic": {"subset_size": [21]}, "scene": stereo_plate()},
                     tmp_path)
    assert d.cameras == ("cam1", "cam0") and d.camera == "cam1"


# ---- the ROI and the truth ----------------------------------------------------------------------------
def test_stereo_roi_keeps_the_pixels_whose_point_camera_1_sees_inside_the_specimen():
    """Camera 1 moved 12 mm aside sees only part of the plate: the ROI is a strict part of camera
    0's specimen pixels; every ROI pixel's point (projected by a pinhole written here) lands inside
    camera 1's image, and every specimen pixel whose point lands outside camera 1's image (by more
    than the margin) is out of the ROI."""
    scene = scene_from_dict(stereo_plate(aside_mm=12.0), ".")
    margin = 2
    prep = stereo.prepare(scene, ("cam0", "cam1"), 1, margin)
    from glsim.render import Renderer
    with Renderer(scene.replace(noise=None), mesh=prep.base.mesh) as r:
        mask0 = r.render("cam0", 0, truth=True).truth.mask
    roi = prep.base.roi
    assert roi.any() and roi.sum() < 0.8 * mask0.sum() and not (roi & ~mask0).any()
    rows, cols = np.nonzero(mask0)
    pts = np.stack([cols, rows], 1).astype(float)
    t = points_truth(mesh_geometry(prep.base.mesh), scene.camera("cam0"), pts, 1)
    cam1 = scene.camera("cam1")
    W, H = cam1.size
    for X in (t.X_undeformed, t.X_deformed):
        uv = pinhole(cam1, X)
        inside = (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5)
        far_out = (uv[:, 0] < -margin - 1) | (uv[:, 0] > W + margin) | (uv[:, 1] < -margin - 1) | (uv[:, 1] > H + margin)
        assert inside[roi[rows, cols]].all()
        assert not roi[rows, cols][far_out].any() and far_out.any()


def test_truth_at_subset_centres_is_the_imposed_rigid_translation_in_camera_0s_frame():
    """The plate moved by t (its own axes): the truth displacement at every centre is R·t (R the
    plate's pose, written out); the reference position lies on the plate's plane and projects back
    to the centre's pixel."""
    shift = (0.15, -0.1, 0.4)
    scene = scene_from_dict(stereo_plate(shift_mm=shift), ".")
    prep = stereo.prepare(scene, ("cam0", "cam1"), 1, 2)
    c = quick.grid_centres(prep.base.roi, 21, 10).astype(float)
    t = stereo.truth_mm(prep, c[:, 0], c[:, 1])
    R = plate_rotation()
    assert np.allclose(R, rodrigues([0.0, -math.radians(10.0), 0.0]))
    assert t["truth_valid"].all() and len(c) > 100
    d = np.stack([t["truth_U"], t["truth_V"], t["truth_W"]], 1)
    np.testing.assert_allclose(d, np.broadcast_to(R @ np.array(shift), d.shape), atol=1e-12)
    X = np.stack([t["truth_X"], t["truth_Y"], t["truth_Z"]], 1)
    np.testing.assert_allclose((X - [0, 0, 300.0]) @ R[:, 2], 0, atol=1e-9)
    np.testing.assert_allclose(pinhole(scene.camera("cam0"), X), c, atol=1e-7)
    np.testing.assert_allclose(t["scale"], X[:, 2] / 3000.0)


def stereo_spec(tmp_path: Path, **top) -> Path:
    return write_spec(tmp_path / "spec.toml", stereo_plate(sigma=1.0, bit_depth=8), engine="pyvale3d",
                      dic={"subset_size": [21], "subset_step": 12}, realisations={"noise_seeds": [1, 2, 3]},
                      rank={"by": "p95_abs_W_mm"}, **top)


@pytest.mark.slow   # glsim design end to end
def test_stereo_rows_maps_and_ranking_against_injected_errors(tmp_path, monkeypatch, capsys):
    import glsim.workflows.design.cli as cli
    scene = scene_from_dict(stereo_plate(sigma=1.0, bit_depth=8), ".")
    eng = StandIn(scene, 1)
    monkeypatch.setattr(cli, "make_engine", lambda name: eng)
    spec, out = stereo_spec(tmp_path), tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "spec.toml"]
    # the exchange: verify/dic.py's format, three states of two images, the scene's rig as calibration
    exchange, manifest = eng.seen[0]
    assert [len(s["images"]["16"]) for s in manifest["states"]] == [2, 2, 2]
    assert manifest["runs"][0]["bit_depth"] == 16 and manifest["runs"][0]["shape_function"] == "AFFINE"
    assert json.loads((exchange / manifest["calibration"]).read_text()) == json.loads(json.dumps(
        pyvale_calibration(scene.camera("cam0"), scene.camera("cam1"))))
    images = [tifffile.imread(exchange / n) for s in manifest["states"] for n in s["images"]["16"]]
    assert all(im.dtype == np.uint16 and im.shape == (256, 256) for im in images)
    assert not np.array_equal(images[0], images[2])      # the static pair has its own noise field
    res = json.loads((out / "results.json").read_text())
    assert res["engine"] == "pyvale3d" and res["cameras"] == ["cam0", "cam1"] and res["rank_by"] == "p95_abs_W_mm"
    r = res["ranking"][0]
    assert r["realisations"] == 3
    n = r["subsets"]
    assert r["valid_share"] == pytest.approx(1 - math.ceil(n / 7) / n)
    assert r["rms_bias_W_mm"] == pytest.approx(BIAS["W"], rel=1e-6)
    assert r["rms_bias_mm"] == pytest.approx(math.sqrt(BIAS["U"] ** 2 + BIAS["V"] ** 2 + BIAS["W"] ** 2), rel=1e-6)
    assert r["median_noise_W_mm"] == pytest.approx(SPREAD, rel=1e-6)         # std of (−s, 0, s), ddof = 1
    assert r["median_noise_mm"] == pytest.approx(SPREAD, rel=1e-6)
    assert r["p95_abs_W_mm"] == pytest.approx(BIAS["W"] + SPREAD, rel=1e-6)   # the top third: bias + s
    assert r["noise_floor_W_mm"] == pytest.approx(SPREAD * math.sqrt(2 / 3), rel=1e-6)
    assert r["noise_floor_Z_mm"] == pytest.approx(SPREAD * math.sqrt(2 / 3) / math.sqrt(2), rel=1e-6)
    assert r["p95_abs_Z_mm"] == pytest.approx(BIAS["Z"], rel=1e-6)
    assert r["mm_per_px"] == pytest.approx(0.1, rel=0.02)
    html = (out / "report.html").read_text()
    assert "p95_abs_W_mm" in html and "stereo pair cam0" in html and html.count("data:image/png;base64,") == 2
    # resumed: every row reused, no engine call
    calls = eng.calls
    assert main([str(spec), "-o", str(out), "-q"]) == 0 and eng.calls == calls


def test_the_rig_handed_to_the_engine_is_in_the_row_key_and_2d_keys_do_not_see_it(tmp_path, monkeypatch):
    design = check_design({"engine": "pyvale3d", "dic": {"subset_size": [21]}, "scene": stereo_plate()}, tmp_path)
    keys = [r.key for r in design_run.rows(design, "pyvale3d")]
    exact = design_run.rig_cameras

    def off_rig(d, scene, out=None):
        c0, c1 = exact(d, scene)
        return c0, dataclasses.replace(c1, fx=c1.fx * 1.001)
    monkeypatch.setattr(design_run, "rig_cameras", off_rig)
    moved = [r.key for r in design_run.rows(design, "pyvale3d")]
    assert len(keys) == 2 and not set(keys) & set(moved)
    flat = check_design({"engine": "pyvale2d", "dic": {"subset_size": [21]}, "scene": plate_scene(size=(256, 256))},
                        tmp_path)
    before = [r.key for r in design_run.rows(flat, "pyvale2d")]
    monkeypatch.setattr(design_run, "rig_cameras", lambda d, s, out=None: pytest.fail("a 2-D design asked for a rig"))
    assert [r.key for r in design_run.rows(flat, "pyvale2d")] == before


def test_missing_stereo_engine_says_how_to_make_it_and_runs_the_quick_mode_on_camera_0(tmp_path, capsys, monkeypatch):
    import glsim.workflows.design.cli as cli
    from glsim.workflows.design.engine import Pyvale3D
    monkeypatch.setattr(cli, "make_engine", lambda name: Pyvale3D(python=tmp_path / "absent" / "python"))
    out = tmp_path / "out"
    assert main([str(stereo_spec(tmp_path)), "-o", str(out), "-q"]) == 0
    err = capsys.readouterr().err
    assert "make .venv-verify/.pyvale-installed" in err and "quick mode only" in err
    res = json.loads((out / "results.json").read_text())
    assert res["engine"] == "quick" and res["rank_by"] == "quick_sigma_px" and len(res["rows"]) == 1
    assert res["ranking"][0]["quick_sigma_px"] > 0
