"""Pinhole camera with OpenCV's distortion model, in numpy (the CPU oracle).

Conventions: millimetres; OpenCV camera axes (x right, y down, z forward);
world→camera pose ``X_cam = R·X_world + t``; pixel centres at integer
coordinates with the top-left pixel's centre at (0, 0). ``uv`` arrays are
``(..., 2)`` as (u, v) = (column, row). Normalized coordinates are
``(X/Z, Y/Z)`` before distortion (``xn``) and after it (``xd``).

``shaders/camera.glsl`` implements the same functions, with the same names and
argument order, for the GPU.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field, fields

import numpy as np

from glsim.errors import SceneError, check
from glsim.limits import MAX_COORDINATE_MM, MAX_DISTORTION, MAX_FOCAL_PX

# Radius up to which valid_radius() checks monotonicity: tan(84.3°).
MAX_CHECKED_RADIUS = 10.0
# Step halvings per Newton iteration in undistort before giving up (as in camera.glsl).
MAX_HALVINGS = 20

_DISTORTION_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")


# ---------------------------------------------------------------------------
# Distortion model (k = 12-vector in OpenCV order)
# ---------------------------------------------------------------------------

def _radial(r2, k):
    """Radial factor and its derivative with respect to r²; also the denominator."""
    k1, k2, _, _, k3, k4, k5, k6 = k[:8]
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * r2 * k6)
    radial = num / den
    return radial, (dnum - radial * dden) / den, den


def distort(xn, k):
    """Apply OpenCV's distortion to normalized points ``xn`` (..., 2) → ``xd`` (..., 2).

    ``k`` is the 12-vector ``(k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4)``.
    """
    xn = np.asarray(xn, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    x, y = xn[..., 0], xn[..., 1]
    p1, p2, s1, s2, s3, s4 = k[2], k[3], k[8], k[9], k[10], k[11]
    r2 = x * x + y * y
    radial, _, _ = _radial(r2, k)
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + r2 * (s1 + s2 * r2)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + r2 * (s3 + s4 * r2)
    return np.stack([xd, yd], axis=-1)


def distort_jacobian(xn, k):
    """Analytic Jacobian ``d xd / d xn`` of :func:`distort`, shape (..., 2, 2), ``J[..., i, j] = d xd_i / d xn_j``."""
    xn = np.asarray(xn, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    x, y = xn[..., 0], xn[..., 1]
    p1, p2, s1, s2, s3, s4 = k[2], k[3], k[8], k[9], k[10], k[11]
    r2 = x * x + y * y
    radial, dradial, _ = _radial(r2, k)
    cross = 2.0 * x * y * dradial
    sx = 2.0 * (s1 + 2.0 * s2 * r2)
    sy = 2.0 * (s3 + 2.0 * s4 * r2)
    j = np.empty(xn.shape[:-1] + (2, 2))
    j[..., 0, 0] = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x + x * sx
    j[..., 0, 1] = cross + 2.0 * p1 * x + 2.0 * p2 * y + y * sx
    j[..., 1, 0] = cross + 2.0 * p1 * x + 2.0 * p2 * y + x * sy
    j[..., 1, 1] = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x + y * sy
    return j


@functools.lru_cache(maxsize=256)
def _valid_radius_cached(k: tuple) -> float:
    k = np.asarray(k)

    def increasing(r):
        # d/dr [r·radial(r²)] = radial + 2 r² radial'; a vanishing denominator also ends validity.
        r2 = r * r
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            radial, dradial, den = _radial(r2, k)
            return (den > 0.0) & (radial + 2.0 * r2 * dradial > 0.0)

    r = np.linspace(0.0, MAX_CHECKED_RADIUS, 100_001)
    bad = np.flatnonzero(~increasing(r))
    if bad.size == 0:
        return math.inf
    if bad[0] == 0:
        return 0.0
    lo, hi = float(r[bad[0] - 1]), float(r[bad[0]])
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if increasing(np.float64(mid)):
            lo = mid
        else:
            hi = mid
    return lo


def valid_radius(k) -> float:
    """Normalized undistorted radius up to which ``r ↦ r·radial(r)`` strictly increases.

    Beyond it the model folds back and (un)distortion is meaningless. Only the
    radial terms (k1..k6) count. Checked up to ``MAX_CHECKED_RADIUS`` = 10
    (tan 84.3°): returns ``math.inf`` when still increasing there.
    """
    return _valid_radius_cached(tuple(float(c) for c in np.asarray(k, dtype=np.float64)))


def undistort(xd, k, tol=1e-14, max_iter=30):
    """Invert :func:`distort`: normalized distorted ``xd`` (..., 2) → ``(xn, ok)``.

    Damped Newton started at ``xn = xd``, halving the step while the residual
    does not fall; converged when ``|distort(xn) − xd| ≤ tol·(1 + |xd|)``.
    ``ok`` is False where it did not converge or ``|xn|`` is not below
    :func:`valid_radius`; there ``xn`` is 0 (never NaN or inf).
    """
    xd = np.asarray(xd, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    finite = np.all(np.isfinite(xd), axis=-1)
    if not np.any(k):
        ok = finite
        return np.where(ok[..., None], xd, 0.0), ok

    shape = xd.shape
    target = np.where(finite[..., None], xd, 0.0).reshape(-1, 2)
    thresh = tol * (1.0 + np.linalg.norm(target, axis=-1))
    xn = target.copy()
    res = np.linalg.norm(distort(xn, k) - target, axis=-1)
    active = res > thresh
    for _ in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        x, f = xn[idx], distort(xn[idx], k) - target[idx]
        j = distort_jacobian(x, k)
        det = j[:, 0, 0] * j[:, 1, 1] - j[:, 0, 1] * j[:, 1, 0]
        singular = ~(np.abs(det) > 0.0)
        det = np.where(singular, 1.0, det)
        step = -np.stack([j[:, 1, 1] * f[:, 0] - j[:, 0, 1] * f[:, 1],
                          j[:, 0, 0] * f[:, 1] - j[:, 1, 0] * f[:, 0]], axis=-1) / det[:, None]
        lam = np.ones(idx.size)
        accepted = np.zeros(idx.size, dtype=bool)
        new_x, new_res = x.copy(), res[idx].copy()
        for _ in range(MAX_HALVINGS):
            todo = np.flatnonzero(~accepted & ~singular)
            if todo.size == 0:
                break
            trial = x[todo] + lam[todo, None] * step[todo]
            trial_res = np.linalg.norm(distort(trial, k) - target[idx[todo]], axis=-1)
            better = trial_res < res[idx[todo]]
            sel = todo[better]
            new_x[sel], new_res[sel] = trial[better], trial_res[better]
            accepted[sel] = True
            lam[todo] *= 0.5
        xn[idx], res[idx] = new_x, new_res
        active[idx] = accepted & (new_res > thresh[idx])  # an unaccepted step means stuck: give up

    r = np.linalg.norm(xn, axis=-1)
    ok = ((res <= thresh) & (r < valid_radius(k))).reshape(shape[:-1]) & finite
    xn = np.where(ok[..., None], xn.reshape(shape), 0.0)
    return xn, ok


# ---------------------------------------------------------------------------
# Intrinsics (intr = fx, fy, skew, cx, cy in px)
# ---------------------------------------------------------------------------

def pixel_to_normalized(uv, intr):
    """Pixel coordinates (..., 2) → normalized distorted coordinates ``xd`` (inverse of K)."""
    uv = np.asarray(uv, dtype=np.float64)
    fx, fy, skew, cx, cy = np.asarray(intr, dtype=np.float64)
    yd = (uv[..., 1] - cy) / fy
    xd = (uv[..., 0] - cx - skew * yd) / fx
    return np.stack([xd, yd], axis=-1)


def normalized_to_pixel(xd, intr):
    """Normalized distorted ``xd`` (..., 2) → pixels: ``u = fx·xd + skew·yd + cx``, ``v = fy·yd + cy``."""
    xd = np.asarray(xd, dtype=np.float64)
    fx, fy, skew, cx, cy = np.asarray(intr, dtype=np.float64)
    return np.stack([fx * xd[..., 0] + skew * xd[..., 1] + cx, fy * xd[..., 1] + cy], axis=-1)


# ---------------------------------------------------------------------------
# Camera
# ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Distortion:
    """OpenCV distortion coefficients (dimensionless; no tilt terms)."""

    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    k4: float = 0.0
    k5: float = 0.0
    k6: float = 0.0
    s1: float = 0.0
    s2: float = 0.0
    s3: float = 0.0
    s4: float = 0.0

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                value = math.nan
            if not math.isfinite(value):
                raise SceneError(f"distortion.{f.name}", f"must be a finite number, got {getattr(self, f.name)!r}",
                                 "give OpenCV distortion coefficients as plain numbers (0 for unused terms)")
            object.__setattr__(self, f.name, value)

    @classmethod
    def from_opencv(cls, seq) -> "Distortion":
        """From an OpenCV ``distCoeffs`` sequence of 4, 5, 8 or 12 values."""
        values = [float(v) for v in np.asarray(seq, dtype=np.float64).ravel()]
        if len(values) not in (4, 5, 8, 12):
            fix = ("tilt terms (tau_x, tau_y) are not supported; drop them" if len(values) == 14
                   else "give (k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]])")
            raise SceneError("distortion", f"needs 4, 5, 8 or 12 coefficients, got {len(values)}", fix)
        return cls(*values)

    @functools.cached_property
    def values(self) -> tuple[float, ...]:
        """The 12 coefficients in OpenCV order as a tuple (made once)."""
        return tuple(getattr(self, n) for n in _DISTORTION_NAMES)

    @property
    def coeffs(self) -> np.ndarray:
        """The 12-vector in OpenCV order (a new array each time)."""
        return np.array(self.values)

    @functools.cached_property
    def is_zero(self) -> bool:
        return not any(self.values)

    def valid_radius(self) -> float:
        """See :func:`valid_radius`."""
        return _valid_radius_cached(self.values)


_IDENTITY = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


@dataclass(frozen=True)
class Camera:
    """A pinhole camera with distortion.

    ``size`` is (W, H) px; ``fx, fy, cx, cy, skew`` px (``skew`` = K[0, 1]);
    ``R`` (3×3) and ``t`` (mm) map world to camera: ``X_cam = R·X_world + t``.
    ``R`` and ``t`` may be given as arrays; they are stored as nested tuples.
    """

    name: str
    size: tuple
    fx: float
    fy: float
    cx: float
    cy: float
    skew: float = 0.0
    distortion: Distortion = field(default_factory=Distortion)
    R: tuple = _IDENTITY
    t: tuple = (0.0, 0.0, 0.0)
    bit_depth: int = 8

    def __post_init__(self):
        set_ = functools.partial(object.__setattr__, self)
        size = tuple(self.size) if isinstance(self.size, (tuple, list, np.ndarray)) else ()
        if len(size) != 2 or not all(_is_int(s) and s > 0 for s in size):
            raise SceneError("size", f"must be two positive integers (W, H) in pixels, got {self.size!r}",
                             "give the sensor size in pixels, e.g. [2448, 2048]")
        set_("size", (int(size[0]), int(size[1])))
        for key in ("fx", "fy", "cx", "cy", "skew"):
            value = _finite(getattr(self, key), key, "give it in pixels")
            if key in ("fx", "fy") and value <= 0:
                raise SceneError(key, f"must be > 0, got {value:g}", "give the focal length in pixels")
            set_(key, value)
        if not isinstance(self.distortion, Distortion):
            raise SceneError("distortion", f"must be a Distortion, got {type(self.distortion).__name__}",
                             "build it with Distortion(k1=...) or Distortion.from_opencv(coeffs)")
        if not _is_int(self.bit_depth) or int(self.bit_depth) not in (8, 10, 12, 16):
            raise SceneError("bit_depth", f"must be 8, 10, 12 or 16, got {self.bit_depth!r}",
                             "give the sensor's bits per pixel")
        set_("bit_depth", int(self.bit_depth))
        set_("R", check_rotation(self.R))
        t = np.asarray(self.t, dtype=np.float64) if _numeric(self.t) else np.full(1, np.nan)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise SceneError("t", f"must be 3 finite numbers (mm), got {self.t!r}",
                             "give the world→camera translation [tx, ty, tz] in mm")
        set_("t", tuple(float(v) for v in t))

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    @property
    def K(self) -> np.ndarray:
        """3×3 intrinsic matrix (px), skew at K[0, 1]."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def intrinsic_values(self) -> tuple[float, ...]:
        """``(fx, fy, skew, cx, cy)`` (px) as a tuple: a cache key, made without numpy."""
        return self.fx, self.fy, self.skew, self.cx, self.cy

    @property
    def intrinsics(self) -> np.ndarray:
        """``[fx, fy, skew, cx, cy]`` (px), the ``intr`` argument of the pure functions."""
        return np.array(self.intrinsic_values)

    @property
    def rotation(self) -> np.ndarray:
        return np.array(self.R)

    @property
    def translation(self) -> np.ndarray:
        return np.array(self.t)

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates (mm), ``−Rᵀt``."""
        return -self.rotation.T @ self.translation


def check_ranges(cam: Camera, key: str) -> None:
    """SceneError naming ``key.fx`` (``key.distortion.k1``, ``key.pose``, …) where a scene camera's
    intrinsics, distortion or centre lie outside glsim's ranges (:mod:`glsim.limits`). Finite is not
    enough: fx = 1e300 or k1 = 1e300 overflow the projection, and the backends would fail differently.
    Only the scene's own cameras are checked: internal ones (the reference camera) have their own
    scale."""
    for name in ("fx", "fy"):
        v = getattr(cam, name)
        check(v <= MAX_FOCAL_PX, f"{key}.{name}", f"{v:g} px is more than glsim's limit of {MAX_FOCAL_PX:g} px",
              "give the focal length in pixels: the lens's focal length over the pixel pitch, "
              "e.g. 30 mm / 0.0044 mm = 6818")
    for name, what in (("cx", "the principal point's u, near (W − 1)/2"), ("cy", "the principal point's v, "
                       "near (H − 1)/2"), ("skew", "K[0, 1], usually 0")):
        v = getattr(cam, name)
        check(abs(v) <= MAX_FOCAL_PX, f"{key}.{name}", f"{v:g} px lies beyond glsim's limit of ±{MAX_FOCAL_PX:g} px",
              f"give {what}, in pixels")
    for name, v in zip(_DISTORTION_NAMES, cam.distortion.values):
        check(abs(v) <= MAX_DISTORTION, f"{key}.distortion.{name}",
              f"{v:g} lies beyond glsim's limit of ±{MAX_DISTORTION:g}",
              "give OpenCV's dimensionless coefficients (calibrations give |k| below 100)")
    far = float(np.abs(cam.center).max())
    check(far <= MAX_COORDINATE_MM, f"{key}.pose", f"puts camera {cam.name} {far:g} mm from the world origin "
          f"along an axis, beyond glsim's limit of {MAX_COORDINATE_MM:g} mm",
          "give the pose in mm (t, look_at, stereo Tx Ty Tz) with the specimen near the world origin")


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _numeric(v) -> bool:
    try:
        np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return True


def _finite(v, key, fix) -> float:
    if isinstance(v, (bool, np.bool_)) or not _numeric(v) or np.ndim(v) != 0 or not math.isfinite(float(v)):
        raise SceneError(key, f"must be a finite number, got {v!r}", fix)
    return float(v)


def check_rotation(R) -> tuple:
    fix = "give a proper rotation matrix, e.g. from a Rodrigues vector with glsim.scene.camera.rodrigues(rvec)"
    m = np.asarray(R, dtype=np.float64) if _numeric(R) else np.full(1, np.nan)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise SceneError("R", f"must be a 3×3 matrix of finite numbers, got {R!r}", fix)
    off = float(np.max(np.abs(m.T @ m - np.eye(3))))
    det = float(np.linalg.det(m))
    if off > 1e-6 or abs(det - 1.0) > 1e-6:
        raise SceneError("R", f"is not a rotation: max |RᵀR − I| = {off:.3g}, det = {det:.9g} "
                              "(needs orthonormal with det +1 to 1e-6)", fix)
    return tuple(tuple(float(v) for v in row) for row in m)


# ---------------------------------------------------------------------------
# Projection and back-projection
# ---------------------------------------------------------------------------

def to_camera(X_world, cam: Camera):
    """World points (..., 3) mm → camera frame (..., 3) mm."""
    return np.asarray(X_world, dtype=np.float64) @ cam.rotation.T + cam.translation


def project_camera_frame(X_cam, cam: Camera):
    """Camera-frame points (..., 3) → ``(uv, ok)``.

    ``ok`` is False for Z ≤ 0 or a normalized radius not below the valid
    radius; there ``uv`` is the principal point (finite).
    """
    X_cam = np.asarray(X_cam, dtype=np.float64)
    z = X_cam[..., 2]
    in_front = z > 0.0
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        xn = X_cam[..., :2] / np.where(in_front, z, 1.0)[..., None]
        k = cam.distortion.coeffs
        ok = in_front & (np.hypot(xn[..., 0], xn[..., 1]) < valid_radius(k))
    xn = np.where(ok[..., None], xn, 0.0)
    return normalized_to_pixel(distort(xn, k), cam.intrinsics), ok


def project(X_world, cam: Camera):
    """World points (..., 3) mm → ``(uv, ok)`` pixels; see :func:`project_camera_frame`."""
    return project_camera_frame(to_camera(X_world, cam), cam)


def pixel_rays(uv, cam: Camera):
    """Pixel coordinates (..., 2) → ``(d, ok)``: unit ray directions in the camera frame.

    Where undistortion fails (``ok`` False) ``d`` is the optical axis (0, 0, 1).
    """
    xn, ok = undistort(pixel_to_normalized(uv, cam.intrinsics), cam.distortion.coeffs)
    d = np.concatenate([xn, np.ones(xn.shape[:-1] + (1,))], axis=-1)
    return d / np.linalg.norm(d, axis=-1, keepdims=True), ok


def pixel_grid(cam: Camera, spp: int = 1, aperture: float = 1.0):
    """Sample coordinates (H·s, W·s, 2) as (u, v) px for s×s supersampling, s = √spp.

    Sample i of s along an axis sits at offset (i + 0.5)/s − 0.5 from the
    pixel centre; with spp = 1 this is the pixel centres. ``aperture`` < 1 (√ of the sensor's
    fill factor) scales the offsets: pixel c's samples at c + aperture·((i + 0.5)/s − 0.5),
    in float64 as shaders/rays.frag and owners.glsl place them.
    """
    s = math.isqrt(spp) if _is_int(spp) and spp > 0 else 0
    if s * s != spp or s == 0:
        raise SceneError("spp", f"must be a perfect square (1, 4, 9, 16, ...), got {spp!r}",
                         "use samples per pixel = s² for an s×s sub-pixel grid")
    if aperture != 1.0:
        off = (np.arange(s) + 0.5) / s - 0.5
        u = (np.arange(cam.width)[:, None] + aperture * off).ravel()
        v = (np.arange(cam.height)[:, None] + aperture * off).ravel()
        return np.stack(np.meshgrid(u, v), axis=-1)
    u = (np.arange(cam.width * s) + 0.5) / s - 0.5
    v = (np.arange(cam.height * s) + 0.5) / s - 0.5
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv], axis=-1)


# ---------------------------------------------------------------------------
# Pose helpers
# ---------------------------------------------------------------------------

def _skew3(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def rodrigues(rvec):
    """Rotation vector (axis·angle, radians) → 3×3 rotation matrix (as cv2.Rodrigues)."""
    w = np.asarray(rvec, dtype=np.float64).reshape(3)
    theta2 = float(w @ w)
    theta = math.sqrt(theta2)
    if theta < 1e-4:  # Taylor series avoid 0/0; truncation error < 1e-17
        a, b = 1.0 - theta2 / 6.0, 0.5 - theta2 / 24.0
    else:
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta2
    W = _skew3(w)
    return np.eye(3) + a * W + b * (W @ W)


def rotation_xyz(theta, phi, psi):
    """``Rz(psi)·Ry(phi)·Rx(theta)``, angles in degrees (MatchID/pyvale stereo convention)."""
    tx, ty, tz = np.radians([theta, phi, psi])
    cx, sx, cy, sy, cz, sz = np.cos(tx), np.sin(tx), np.cos(ty), np.sin(ty), np.cos(tz), np.sin(tz)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    return rz @ ry @ rx


def stereo_pose(cam1_R, cam1_t, Tx, Ty, Tz, theta, phi, psi):
    """Camera 1's world→camera pose ``(R2, t2)`` from camera 0's and the stereo extrinsics.

    The extrinsics map camera 0's frame to camera 1's: ``X_cam1 = Rs·X_cam0 + T``
    with ``Rs = rotation_xyz(theta, phi, psi)`` (degrees) and ``T = (Tx, Ty, Tz)`` mm.
    """
    rs = rotation_xyz(theta, phi, psi)
    r1 = np.asarray(cam1_R, dtype=np.float64)
    t1 = np.asarray(cam1_t, dtype=np.float64)
    return rs @ r1, rs @ t1 + np.array([Tx, Ty, Tz], dtype=np.float64)


def look_at(eye, target, up):
    """World→camera ``(R, t)`` for a camera at ``eye`` looking at ``target`` (mm).

    OpenCV axes: z points at the target, y (image down) is as close to −up as
    possible, x = y × z completes a right-handed frame.
    """
    eye, target, up = (np.asarray(v, dtype=np.float64) for v in (eye, target, up))
    z = target - eye
    if not np.linalg.norm(z) > 0:
        raise SceneError("target", "coincides with the camera position", "place the camera away from its target")
    z = z / np.linalg.norm(z)
    x = np.cross(-up, z)
    if not np.linalg.norm(x) > 1e-12 * max(np.linalg.norm(up), 1e-300):
        raise SceneError("up", f"is parallel to the viewing direction {z.tolist()}",
                         "give an up vector that is not along the line from camera to target")
    x = x / np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ eye
