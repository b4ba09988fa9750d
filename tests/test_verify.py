"""glsim's side of `glsim verify` (no pyvale needed): the exchange folder, the calibration in
pyvale's convention, the truth at subset centres and the Tables 4/5 statistics."""
import ast
import json
from pathlib import Path

import numpy as np
import pytest
import tifffile

from glsim.dic import cli, verify
from glsim.io import calibfiles
from glsim.scene.camera import Camera, Distortion, project, rotation_xyz, stereo_pose, to_camera
from glsim.errors import GlsimError

SIZE = (162, 123)
RUN = {"name": "synthetic", "shape_function": "AFFINE", "bit_depth": 16}


@pytest.fixture(scope="module")
def exchange(tmp_path_factory) -> Path:
    """A small exchange folder rendered with the CPU oracle (same geometry as GL)."""
    out = tmp_path_factory.mktemp("exchange")
    verify.write_exchange(out, size=SIZE, mesh_divisions=8, backend="cpu", runs=[RUN])
    return out


# ---- pyvale's camera model, written from its documentation and C++ source --------------------
def _pyvale_rotation(theta, phi, psi):
    """R = Rz(psi)·Ry(phi)·Rx(theta), degrees (pyvale's stereoutil rotation_from_euler)."""
    t, p, s = np.radians([theta, phi, psi])
    rx = np.array([[1, 0, 0], [0, np.cos(t), -np.sin(t)], [0, np.sin(t), np.cos(t)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(s), -np.sin(s), 0], [np.sin(s), np.cos(s), 0], [0, 0, 1]])
    return rz @ ry @ rx


def _pyvale_project(X_cam0: np.ndarray, calib: dict, camera: int) -> np.ndarray:
    """Pixel coordinates in pyvale's camera ``camera`` of points in camera 0's frame (mm)."""
    X = X_cam0
    if camera == 1:
        X = X @ _pyvale_rotation(*calib["rotation"]).T + np.asarray(calib["translation"])
    c = calib[f"cam{camera}"]
    k1, k2, p1, p2, k3 = c["distortion"]
    x, y = X[:, 0] / X[:, 2], X[:, 1] / X[:, 2]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([c["fx"] * xd + c["fs"] * yd + c["cx"], c["fy"] * yd + c["cy"]], axis=1)


def _rig(first_pose: bool) -> tuple[Camera, Camera]:
    """Two distorted cameras with skew; camera 0 at the world origin or placed elsewhere."""
    R1 = rotation_xyz(2.0, -3.0, 1.5) if first_pose else np.eye(3)
    t1 = np.array([5.0, -8.0, 12.0]) if first_pose else np.zeros(3)
    R2, t2 = stereo_pose(R1, t1, -310.0, 4.0, 85.0, 1.2, 29.0, -0.7)
    cam1 = Camera("a", (1624, 1234), 6818.0, 6825.0, 811.0, 618.0, skew=0.8,
                  distortion=Distortion(k1=-0.08, k2=0.12, p1=1e-3, p2=-5e-4, k3=-0.05), R=R1, t=t1)
    cam2 = Camera("b", (1624, 1234), 6790.0, 6801.0, 805.0, 621.0, skew=-0.4,
                  distortion=Distortion(k1=0.05, k2=-0.1, p1=-7e-4, p2=9e-4, k3=0.02), R=R2, t=t2)
    return cam1, cam2


# ---- calibration convention -----------------------------------------------------------------
def test_euler_xyz_inverts_rotation_xyz():
    rng = np.random.default_rng(1)
    for angles in rng.uniform([-170, -85, -170], [170, 85, 170], size=(50, 3)):
        back = calibfiles.euler_xyz(rotation_xyz(*angles))
        np.testing.assert_allclose(back, angles, atol=1e-10)
        np.testing.assert_allclose(rotation_xyz(*back), rotation_xyz(*angles), atol=1e-15)


@pytest.mark.parametrize("first_pose", [False, True])
def test_pyvale_calibration_reprojects_like_glsim(first_pose):
    cam1, cam2 = _rig(first_pose)
    calib = json.loads(json.dumps(calibfiles.pyvale_calibration(cam1, cam2)))   # as written to disk
    rng = np.random.default_rng(2)
    X_world = rng.uniform([-60, -50, 560], [60, 50, 640], size=(200, 3))
    X_cam0 = to_camera(X_world, cam1)
    for camera, cam in ((0, cam1), (1, cam2)):
        uv, ok = project(X_world, cam)
        assert ok.all()
        assert np.max(np.abs(_pyvale_project(X_cam0, calib, camera) - uv)) < 1e-9


def test_pyvale_calibration_of_the_bulge_rig_is_the_stereo_pose():
    cal = calibfiles.pyvale_calibration(*verify.verify_scene(SIZE).cameras)
    np.testing.assert_allclose(cal["rotation"], [0.0, 30.0, 0.0], atol=1e-12)
    assert cal["cam0"]["distortion"] == [0.0] * 5


def test_pyvale_calibration_rejects_terms_pyvale_lacks():
    cam1, cam2 = _rig(False)
    thin_prism = Camera("c", cam2.size, cam2.fx, cam2.fy, cam2.cx, cam2.cy,
                        distortion=Distortion(k1=0.1, s1=1e-3), R=cam2.R, t=cam2.t)
    with pytest.raises(GlsimError, match="k1, k2, p1, p2, k3"):
        calibfiles.pyvale_calibration(cam1, thin_prism)


# ---- truth at subset centres ------------------------------------------------------------------
def test_sample_bilinear_exact_on_linear_maps_and_masks_gaps():
    H, W = 7, 9
    v, u = np.mgrid[0:H, 0:W].astype(float)
    maps = np.stack([2 * u - 3 * v + 1, v, u + v], axis=-1)
    uv = np.array([[0.25, 0.5], [3.0, 4.0], [7.9, 5.3], [8.0, 6.0]])
    values, valid = verify.sample_bilinear(maps, uv)
    assert valid.all()
    expect = np.stack([2 * uv[:, 0] - 3 * uv[:, 1] + 1, uv[:, 1], uv.sum(axis=1)], axis=1)
    np.testing.assert_allclose(values, expect, atol=1e-12)

    maps[4, 4] = np.nan   # off the specimen
    values, valid = verify.sample_bilinear(maps, np.array([[3.0, 3.0], [3.5, 3.0], [4.0, 4.0], [9.5, 1.0]]))
    assert valid.tolist() == [True, True, False, False]   # zero-weight NaN neighbours do not count
    assert np.isnan(values[2:]).all()


def test_truth_maps_reproject_onto_their_pixels(exchange):
    truth = np.load(exchange / "truth.npz")
    cam1 = verify.verify_scene(SIZE, 8).cameras[0]
    rows, cols = np.nonzero(truth["mask"])
    uv, ok = project(truth["X_step0"][rows, cols], cam1)   # camera 0 is the world frame
    assert ok.all() and np.max(np.abs(uv - np.stack([cols, rows], axis=1))) < 1e-6
    moved = np.linalg.norm(truth["X_step1"] - truth["X_step0"], axis=-1)[truth["mask"]]
    assert 4.9 < moved.max() < 5.2   # the 5 mm bulge (plus the surface fibre's radial motion)


# ---- exchange folder ----------------------------------------------------------------------------
def test_exchange_folder_is_complete_and_consistent(exchange):
    manifest = json.loads((exchange / "manifest.json").read_text())
    assert manifest["format"] == verify.FORMAT and manifest["size"] == list(SIZE)
    assert manifest["calculate_3d"]["subset_size"] == 19 and manifest["calculate_3d"]["subset_step"] == 9
    assert manifest["calculate_3d"]["image_filter_kernel"] == 1
    assert {p.suffix for p in exchange.iterdir()} <= {".json", ".npz", ".tif"}
    assert [s["step"] for s in manifest["states"]] == [0, verify.DEFORMED_STEP]
    for state in manifest["states"]:
        for bits, dtype in (("16", np.uint16), ("8", np.uint8)):
            for name in state["images"][bits]:
                img = tifffile.imread(exchange / name)
                assert img.dtype == dtype and img.shape == SIZE[::-1] and img.max() > img.min()
    roi = tifffile.imread(exchange / manifest["roi"]) > 0
    truth = np.load(exchange / manifest["truth"])
    assert roi.any() and not (roi & ~truth["mask"]).any()
    assert np.isfinite(truth["X_step0"][truth["mask"]]).all() and np.isnan(truth["X_step0"][~truth["mask"]]).all()
    x, y = manifest["seed"]
    assert roi[y, x]
    cameras = verify.verify_scene(SIZE, 8).cameras
    assert json.loads((exchange / manifest["scene"]).read_text())["cameras"][1]["fx"] == cameras[1].fx
    assert json.loads((exchange / manifest["calibration"]).read_text()) == \
        json.loads(json.dumps(calibfiles.pyvale_calibration(*cameras)))


def test_roi_keeps_the_plate_inside_the_radius(exchange):
    roi = tifffile.imread(exchange / "roi.tif") > 0
    X = np.load(exchange / "truth.npz")["X_step0"][roi]
    scene = verify.verify_scene(SIZE, 8)
    local = (X - np.asarray(scene.specimen.t)) @ np.asarray(scene.specimen.R)
    assert np.abs(local[:, 2]).max() < 1e-9   # the undeformed plate surface
    assert np.hypot(local[:, 0], local[:, 1]).max() <= verify.ROI_RADIUS_MM


# ---- comparison -------------------------------------------------------------------------------
def test_difference_rows_report_a_known_bias_and_spread():
    rng = np.random.default_rng(3)
    imposed = rng.uniform(-50, 650, size=(500, 3))
    noise = rng.standard_normal((500, 3))
    noise = (noise - noise.mean(axis=0)) / noise.std(axis=0)       # zero mean, unit std exactly
    bias, spread, M = np.array([2e-4, -3e-5, 7e-4]), np.array([1e-4, 2e-4, 0.0]), 0.088
    rows = verify.difference_rows(imposed + bias + spread * noise, imposed, M)
    assert [r["dir"] for r in rows] == ["X", "Y", "Z"]
    for r, b, s in zip(rows, bias, spread):
        assert r["mean_mm"] == pytest.approx(b, abs=1e-12) and r["std_mm"] == pytest.approx(s, abs=1e-12)
        assert r["mean_px"] == pytest.approx(b / M, abs=1e-10) and r["std_px"] == pytest.approx(s / M, abs=1e-10)


def _synthetic_measurement(exchange: Path, bias: np.ndarray) -> np.ndarray:
    """measured_synthetic.npz: the truth at subset centres on a step-9 grid, shifted by ``bias``."""
    truth = np.load(exchange / "truth.npz")
    roi = tifffile.imread(exchange / "roi.tif") > 0
    y, x = np.mgrid[4:SIZE[1]:9, 4:SIZE[0]:9]
    keep = roi[y, x]
    ss = np.stack([x[keep], y[keep]], axis=1)
    X0, X1 = (truth[k][ss[:, 1], ss[:, 0]] for k in ("X_step0", "X_step1"))
    n = len(ss)
    np.savez(exchange / "measured_synthetic.npz", ss_x=ss[:, 0], ss_y=ss[:, 1],
             X=np.stack([X0, X1]) + bias, U=np.stack([np.zeros_like(X0), X1 - X0]) + bias,
             valid=np.ones((2, n), bool), cost=np.ones((2, n)), stereo_cost=np.ones((2, n)),
             epi_dist_px=np.zeros((2, n)), seconds=np.float64(1.5), pyvale_version=np.str_("test"))
    return X0


def test_report_on_a_synthetic_measurement(exchange, tmp_path):
    bias = np.array([1e-4, -2e-4, 3e-4])
    X0 = _synthetic_measurement(exchange, bias)
    res = verify.report(exchange, tmp_path)
    run = res["runs"][0]
    M = X0[:, 2].mean() / 6818.0 * 1624 / SIZE[0]   # fx scales with the image width
    assert run["n_compared"] == run["n_subsets"] == len(X0) > 20
    assert run["mm_per_px"] == pytest.approx(M, rel=1e-12)
    undeformed, deformed = run["states"]
    assert [r["dir"] for r in deformed["rows"]] == ["X", "Y", "Z", "U", "V", "W"]
    for state in (undeformed, deformed):
        for r in state["rows"]:
            b = bias["XYZUVW".index(r["dir"]) % 3]   # U = X1 − X0 + bias as well
            assert r["mean_mm"] == pytest.approx(b, abs=1e-9) and r["std_mm"] < 1e-9
            assert r["mean_px"] == pytest.approx(b / M, abs=1e-8)
    assert undeformed["rows"][2]["paper_mean_px"] == 8.34e-03
    saved = json.loads((tmp_path / "verify.json").read_text())
    assert saved["runs"][0]["states"][1]["rows"][0]["mean_mm"] == pytest.approx(bias[0], abs=1e-9)
    md = (tmp_path / "verify.md").read_text()
    assert "| undeformed | Z |" in md and "| deformed | W |" in md and "paper mean (px)" in md


def test_cli_compare_and_missing_dic_environment(exchange, tmp_path, capsys):
    _synthetic_measurement(exchange, np.zeros(3))
    assert cli.main(["compare", str(exchange), "--results", str(tmp_path)]) == 0
    assert (tmp_path / "verify.md").exists()
    with pytest.raises(GlsimError, match="make verify"):
        verify.run_dic(exchange, python=tmp_path / "no-python")


def test_dic_script_never_imports_glsim():
    tree = ast.parse((Path(verify.__file__).parents[2] / "verify" / "dic.py").read_text())
    names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
    names += [n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)]
    assert names and not any(name.split(".")[0] == "glsim" for name in names)


def test_a_measurement_declaring_a_huge_array_is_refused_before_it_is_made(exchange, tmp_path, monkeypatch):
    """pyvale's results are read bounded by their .npy headers: an X declaring 10¹² rows is named,
    not allocated (a MemoryError or an OOM kill); the truth named outside the exchange is refused."""
    import io
    import shutil
    import zipfile
    exchange = Path(shutil.copytree(exchange, tmp_path / "exchange"))   # (the module's folder stays intact)
    _synthetic_measurement(exchange, np.zeros(3))
    path = exchange / "measured_synthetic.npz"
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (2, 10**12, 3)})
    with zipfile.ZipFile(path, "w") as zf:
        for k, a in arrays.items():
            buf = io.BytesIO()
            np.save(buf, a)
            zf.writestr(f"{k}.npy", header.getvalue() + a.tobytes() if k == "X" else buf.getvalue())
    with pytest.raises(GlsimError, match="X"):
        verify.report(exchange, tmp_path / "results")
    manifest = json.loads((exchange / "manifest.json").read_text())
    manifest["truth"] = "../elsewhere.npz"
    (exchange / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(GlsimError, match="outside the exchange folder"):
        verify.compare(exchange, {"name": "synthetic"})
