"""glsim.scene.camera against OpenCV (cv2.projectPoints, cv2.undistortPoints, cv2.Rodrigues)."""

import math

import cv2
import numpy as np
import pytest

from glsim.scene.camera import (Camera, Distortion, distort, distort_jacobian, look_at, pixel_grid, pixel_rays, pixel_to_normalized, project, project_camera_frame, rodrigues, rotation_xyz, stereo_pose, to_camera, undistort)
from glsim.errors import SceneError

W, H = 2448, 2048
FX, FY, CX, CY = 1800.0, 1802.5, 1230.3, 1019.7
RVEC = np.array([0.1, -0.25, 0.05])
TVEC = np.array([12.0, -8.0, 950.0])

DISTORTIONS = {
    "none": Distortion(),
    "mild_barrel": Distortion(k1=-0.1),
    "strong_barrel": Distortion(k1=-0.35, k2=0.12),
    "pincushion": Distortion(k1=0.3),
    "full12": Distortion.from_opencv([-0.12, 0.05, 1e-3, -5e-4, -0.01, 0.02, -0.01, 0.005,
                                      1e-3, -2e-4, -1e-3, 3e-4]),
    "rational": Distortion(k1=-0.2, k2=0.05, k3=0.01, k4=0.1, k5=-0.02, k6=0.004),
}
# Folds back at r = 1/sqrt(3·0.35) ≈ 0.976, i.e. distorted radius ≈ 0.651: inside this image.
FOLDING = Distortion(k1=-0.35)
CV_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-16)


def make_camera(distortion=Distortion(), **kw):
    args = dict(name="cam0", size=(W, H), fx=FX, fy=FY, cx=CX, cy=CY, distortion=distortion,
                R=rodrigues(RVEC), t=TVEC)
    args.update(kw)
    return Camera(**args)


def image_grid(nu=41, nv=37):
    """Pixel coordinates covering the whole image, its outer edges and corners included."""
    u, v = np.meshgrid(np.linspace(-0.5, W - 0.5, nu), np.linspace(-0.5, H - 0.5, nv))
    return np.stack([u, v], axis=-1).reshape(-1, 2)


def cv_undistort(uv, cam):
    return cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.distortion.coeffs,
                               criteria=CV_CRITERIA).reshape(-1, 2)


@pytest.mark.parametrize("name", DISTORTIONS)
def test_project_matches_opencv_up_to_corners(name):
    cam = make_camera(DISTORTIONS[name])
    rng = np.random.default_rng(1)
    # Undistorted normalized box reaching 5 % past the image corners.
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [-0.5, H - 0.5], [W - 0.5, H - 0.5]])
    reach = np.abs(cv_undistort(corners, cam)).max(axis=0) * 1.05
    xn = rng.uniform(-reach, reach, size=(2000, 2))
    z = rng.uniform(300.0, 3000.0, size=(2000, 1))
    X_world = (np.hstack([xn * z, z]) - cam.translation) @ cam.rotation
    uv, ok = project(X_world, cam)
    ref, _ = cv2.projectPoints(X_world, RVEC, TVEC, cam.K, cam.distortion.coeffs)
    assert ok.all()
    np.testing.assert_allclose(uv, ref.reshape(-1, 2), rtol=0, atol=1e-9)
    assert (uv.min(axis=0) < [0, 0]).all() and (uv.max(axis=0) > [W, H]).all()


def test_project_with_skew():
    d = DISTORTIONS["full12"]
    cam = make_camera(d, skew=3.7)
    X_world = np.random.default_rng(2).uniform([-400, -300, 200], [400, 300, 900], size=(500, 3))
    xd, _ = cv2.projectPoints(X_world, RVEC, TVEC, np.eye(3), d.coeffs)
    ref = np.c_[xd.reshape(-1, 2), np.ones(len(X_world))] @ cam.K.T
    uv, ok = project(X_world, cam)
    assert ok.all()
    np.testing.assert_allclose(uv, ref[:, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(pixel_to_normalized(uv, cam.intrinsics), xd.reshape(-1, 2), rtol=0, atol=1e-14)


@pytest.mark.parametrize("name", DISTORTIONS)
def test_undistort_and_pixel_rays_match_opencv(name):
    cam = make_camera(DISTORTIONS[name])
    uv = image_grid()
    ref = cv_undistort(uv, cam)
    xn, ok = undistort(pixel_to_normalized(uv, cam.intrinsics), cam.distortion.coeffs)
    assert ok.all()
    np.testing.assert_allclose(xn * cam.fx, ref * cam.fx, rtol=0, atol=1e-9)
    d, ok = pixel_rays(uv, cam)
    assert ok.all()
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(d[:, :2] / d[:, 2:] * cam.fx, ref * cam.fx, rtol=0, atol=1e-9)


@pytest.mark.parametrize("d", [*DISTORTIONS.values(), FOLDING], ids=[*DISTORTIONS, "folding"])
def test_distort_undistort_round_trip(d):
    k = d.coeffs
    r_max = 0.9 * min(d.valid_radius(), 1.5)
    rng = np.random.default_rng(3)
    r, phi = r_max * np.sqrt(rng.uniform(size=3000)), rng.uniform(0, 2 * np.pi, size=3000)
    xn = np.stack([r * np.cos(phi), r * np.sin(phi)], axis=-1).reshape(30, 100, 2)
    back, ok = undistort(distort(xn, k), k)
    assert ok.shape == (30, 100) and ok.all()
    np.testing.assert_allclose(back, xn, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", DISTORTIONS)
def test_jacobian_matches_finite_differences(name):
    k = DISTORTIONS[name].coeffs
    xn = np.random.default_rng(4).uniform(-1.0, 1.0, size=(200, 2))
    h = 1e-6
    fd = np.stack([(distort(xn + h * e, k) - distort(xn - h * e, k)) / (2 * h) for e in np.eye(2)], axis=-1)
    np.testing.assert_allclose(distort_jacobian(xn, k), fd, rtol=0, atol=1e-8)


def test_valid_radius():
    assert Distortion().valid_radius() == math.inf
    assert DISTORTIONS["strong_barrel"].valid_radius() == math.inf  # 1 − 1.05 r² + 0.6 r⁴ > 0 for all r
    assert FOLDING.valid_radius() == pytest.approx(1 / math.sqrt(3 * 0.35), abs=1e-12)
    assert Distortion(k1=-1e-4).valid_radius() == math.inf  # folds at r ≈ 57.7, beyond the checked 10
    assert Distortion(k4=-0.5).valid_radius() == pytest.approx(math.sqrt(2), abs=1e-12)  # denominator → 0


def test_beyond_valid_radius_is_not_ok_and_finite():
    cam = make_camera(FOLDING)
    uv = image_grid()
    xd = pixel_to_normalized(uv, cam.intrinsics)
    rd = np.linalg.norm(xd, axis=-1)
    rd_max = 2 / 3 * FOLDING.valid_radius()  # r·(1 − 0.35 r²) at r² = 1/1.05
    d, ok = pixel_rays(uv, cam)
    assert np.isfinite(d).all()
    assert not ok[rd > rd_max * 1.0001].any() and ok[rd < rd_max * 0.99].all()
    assert (~ok).sum() > 100
    np.testing.assert_array_equal(d[~ok], [[0.0, 0.0, 1.0]] * (~ok).sum())
    xn, ok = undistort(xd, cam.distortion.coeffs)
    assert np.isfinite(xn).all() and (xn[~ok] == 0).all()
    # Forward: points beyond the fold radius are flagged too.
    r = FOLDING.valid_radius()
    uv, ok = project_camera_frame(np.array([[0.99 * r, 0, 1], [1.01 * r, 0, 1], [0, 50 * r, 1]]), cam)
    np.testing.assert_array_equal(ok, [True, False, False])
    assert np.isfinite(uv).all()


def test_non_finite_input_is_not_ok():
    xn, ok = undistort(np.array([[np.nan, 0.1], [0.1, np.inf], [0.1, 0.1]]), DISTORTIONS["full12"].coeffs)
    np.testing.assert_array_equal(ok, [False, False, True])
    assert np.isfinite(xn).all()


def test_points_behind_camera_are_not_ok():
    cam = make_camera(DISTORTIONS["full12"])
    uv, ok = project_camera_frame(np.array([[10.0, 5.0, -100.0], [10.0, 5.0, 0.0], [0.0, 0.0, 0.0],
                                            [10.0, 5.0, 100.0]]), cam)
    np.testing.assert_array_equal(ok, [False, False, False, True])
    assert np.isfinite(uv).all()
    _, ok = project(cam.center + np.outer([-100.0, 100.0], cam.rotation[2]), cam)  # behind, in front
    np.testing.assert_array_equal(ok, [False, True])


def test_rodrigues_matches_opencv():
    rng = np.random.default_rng(5)
    vecs = [np.zeros(3), [1e-9, -2e-9, 0.0], [3e-5, 1e-5, -2e-5], [0, 0, math.pi], [math.pi - 1e-7, 0, 0],
            *rng.normal(size=(20, 3))]
    for v in vecs:
        np.testing.assert_allclose(rodrigues(v), cv2.Rodrigues(np.asarray(v, float))[0], rtol=0, atol=1e-14)


def test_rotation_xyz_composition():
    a, b, c = 12.0, -30.0, 47.0
    rx, ry, rz = (cv2.Rodrigues(np.radians(ang) * e)[0] for ang, e in zip((a, b, c), np.eye(3)))
    np.testing.assert_allclose(rotation_xyz(a, 0, 0), rx, atol=1e-15)
    np.testing.assert_allclose(rotation_xyz(0, b, 0), ry, atol=1e-15)
    np.testing.assert_allclose(rotation_xyz(0, 0, c), rz, atol=1e-15)
    np.testing.assert_allclose(rotation_xyz(a, b, c), rz @ ry @ rx, atol=1e-15)
    np.testing.assert_allclose(rotation_xyz(90, 0, 0) @ [0, 1, 0], [0, 0, 1], atol=1e-15)


def test_stereo_pose_maps_cam1_frame_to_cam2_frame():
    R1, t1 = rodrigues(RVEC), TVEC
    T, angles = np.array([-250.0, 3.0, 40.0]), (1.5, 18.0, -0.7)
    R2, t2 = stereo_pose(R1, t1, *T, *angles)
    cam2 = make_camera(R=R2, t=t2)  # a proper rotation
    X = np.random.default_rng(6).uniform(-100, 100, size=(50, 3))
    X1 = X @ R1.T + t1
    np.testing.assert_allclose(to_camera(X, cam2), X1 @ rotation_xyz(*angles).T + T, rtol=0, atol=1e-10)


def test_look_at_axes():
    eye, target, up = np.array([300.0, -200.0, -1000.0]), np.array([10.0, 20.0, 5.0]), np.array([0.0, 0.0, 1.0])
    R, t = look_at(eye, target, up)
    cam = make_camera(R=R, t=t)
    np.testing.assert_allclose(cam.center, eye, atol=1e-10)
    view = (target - eye) / np.linalg.norm(target - eye)
    np.testing.assert_allclose(R[2], view, atol=1e-15)  # z toward the target
    assert abs(R[1] @ view) < 1e-15 and R[1] @ up < 0  # y ⟂ view, as near −up as possible
    np.testing.assert_allclose(R[1], -(up - (up @ view) * view) / np.linalg.norm(up - (up @ view) * view), atol=1e-15)
    uv, _ = project(np.stack([target, target + 10 * up]), cam)
    np.testing.assert_allclose(uv[0], [CX, CY], atol=1e-9)
    assert uv[1, 1] < CY  # world up is image up
    with pytest.raises(SceneError, match="up: is parallel"):
        look_at(eye, target, target - eye)


def test_pixel_grid():
    cam = make_camera(size=(3, 2))
    np.testing.assert_array_equal(pixel_grid(cam)[1, 2], [2.0, 1.0])
    g = pixel_grid(cam, spp=4)
    assert g.shape == (4, 6, 2)
    np.testing.assert_allclose(g[0, 0], [-0.25, -0.25])
    np.testing.assert_allclose(g[3, 5], [2.25, 1.25])
    centres = g.reshape(2, 2, 3, 2, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(centres, pixel_grid(cam), atol=1e-15)
    with pytest.raises(SceneError, match="spp: must be a perfect square"):
        pixel_grid(cam, spp=2)


def test_camera_properties():
    cam = make_camera(DISTORTIONS["full12"], skew=0.5)
    assert (cam.width, cam.height) == (W, H)
    np.testing.assert_array_equal(cam.K, [[FX, 0.5, CX], [0, FY, CY], [0, 0, 1]])
    np.testing.assert_array_equal(cam.intrinsics, [FX, FY, 0.5, CX, CY])
    np.testing.assert_allclose(to_camera(cam.center, cam), 0.0, atol=1e-12)
    assert isinstance(cam.R, tuple) and isinstance(cam.t, tuple) and hash(cam)
    assert Distortion().is_zero and not cam.distortion.is_zero
    np.testing.assert_array_equal(Distortion.from_opencv([1, 2, 3, 4]).coeffs, [1, 2, 3, 4] + [0] * 8)
    np.testing.assert_array_equal(Distortion.from_opencv(range(1, 9)).coeffs, list(range(1, 9)) + [0] * 4)
    with pytest.raises(SceneError, match="tilt"):
        Distortion.from_opencv(np.zeros(14))
    with pytest.raises(SceneError, match="distortion.k2: must be a finite number"):
        Distortion(k2=math.nan)


@pytest.mark.parametrize("kw, key, match", [
    (dict(fx=-3.0), "fx", r"fx: must be > 0, got -3 — give the focal length in pixels"),
    (dict(fy=0.0), "fy", r"fy: must be > 0.*focal length"),
    (dict(size=(0, 2048)), "size", r"size: must be two positive integers.*sensor size in pixels"),
    (dict(size=(2448.5, 2048)), "size", r"size: must be two positive integers"),
    (dict(R=[[1, 0, 0], [0, 1, 0.01], [0, 0, 1]]), "R", r"R: is not a rotation: max \|RᵀR − I\| = 0\.01.*Rodrigues"),
    (dict(R=np.diag([1.0, 1.0, -1.0])), "R", r"R: is not a rotation.*det = -1.*Rodrigues"),
    (dict(bit_depth=9), "bit_depth", r"bit_depth: must be 8, 10, 12 or 16, got 9 — give the sensor's bits"),
    (dict(cx=math.inf), "cx", r"cx: must be a finite number"),
    (dict(t=(0.0, 1.0)), "t", r"t: must be 3 finite numbers"),
])
def test_camera_validation(kw, key, match):
    with pytest.raises(SceneError, match=match) as info:
        make_camera(**kw)
    assert info.value.key == key
