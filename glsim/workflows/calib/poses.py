"""Target poses for a calibration library: roll, twist, plunge, translation across the field of
view and random mixes, placed balanced over the full common field of view or at its centre.

A pose maps the target frame to camera 0's frame: X_cam0 = R·X_target + t (mm). Poses are
built in the *rig frame*: origin at the point where the optical axes pass closest (camera 0's
axis at the working distance for one camera), z along the bisector of the optical axes, x as
close to camera 0's x as possible. A target at zero motion faces the rig squarely there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from glsim.scene.camera import Camera, project, rodrigues, to_camera
from glsim.errors import SceneError

KINDS = ("translate", "roll", "twist", "plunge", "mixed")
FOVS = ("full", "centre")
CELLS = 3   # the full field of view is split into CELLS × CELLS cells, visited in turn


@dataclass(frozen=True)
class PoseSpec:
    """How poses are drawn (mm, degrees).

    ``fov``: "full" spreads the target centre over the field of view both cameras share, in
    CELLS × CELLS cells visited in turn (so any CELLS² consecutive poses cover it evenly),
    reaching so far that the outer dots touch the image edges (some poses are partly out of
    view: kept, and marked in the ground truth); "centre" keeps it within ``centre_fraction``
    of the half field of view. Each pose has one motion kind from ``kinds``, in turn:
    translate (facing the rig), roll (about the target normal, |angle| ≤ ``roll``), twist
    (tilt about a random in-plane axis by ``tilt[0]``…``tilt[1]``), plunge (along the
    bisector by ± ``plunge`` × working distance), mixed (all of them at random).
    """
    fov: str = "full"
    centre_fraction: float = 0.15
    reach: float = 1.0
    roll: float = 45.0
    tilt: tuple[float, float] = (10.0, 35.0)
    plunge: float = 0.1
    kinds: tuple[str, ...] = KINDS

    def __post_init__(self):
        if self.fov not in FOVS:
            raise SceneError("poses.fov", f"{self.fov!r} is not one of {FOVS}", "use 'full' or 'centre'")
        bad = [k for k in self.kinds if k not in KINDS]
        if bad or not self.kinds:
            raise SceneError("poses.kinds", f"unknown or no kinds {bad}", f"use some of {', '.join(KINDS)}")
        if not 0 <= self.tilt[0] <= self.tilt[1] < 80:
            raise SceneError("poses.tilt", f"{self.tilt} is not a range within [0, 80)°", "give (min, max) in degrees")
        if not 0 <= self.plunge < 0.5:
            raise SceneError("poses.plunge", f"must lie in [0, 0.5), got {self.plunge}",
                             "a fraction of the working distance")
        if not 0 < self.centre_fraction <= 1 or not 0 < self.reach <= 1.5:
            raise SceneError("poses.centre_fraction", "centre_fraction must lie in (0, 1] and reach in (0, 1.5]",
                             "fractions of the half field of view")


@dataclass(frozen=True)
class Pose:
    """One target pose: target → camera 0, X_cam0 = R·X + t (mm), and how it was drawn."""
    R: tuple
    t: tuple
    kind: str
    cell: int            # FOV cell (row-major in CELLS × CELLS), −1 for "centre"

    @property
    def rvec(self) -> np.ndarray:
        import cv2
        return cv2.Rodrigues(np.asarray(self.R, float))[0].ravel()


def rig_frame(cameras: tuple[Camera, ...], distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(B, o): the rig frame in camera 0's frame, X_cam0 = B·X_rig + o (see the module text).

    With one camera, or ``distance`` given, o is on camera 0's axis at ``distance`` (mm)."""
    cam1 = cameras[0]
    axes = [(c.rotation @ cam1.rotation.T).T @ [0.0, 0.0, 1.0] for c in cameras]
    centres = [to_camera(c.center, cam1) for c in cameras]
    if len(cameras) == 1 or distance is not None:
        if distance is None:
            raise SceneError("distance", "one camera has no convergence point", "give the working distance in mm")
        o = np.array([0.0, 0.0, distance])
    else:  # least-squares point closest to all optical axes
        A = sum(np.eye(3) - np.outer(a, a) for a in axes)
        b = sum((np.eye(3) - np.outer(a, a)) @ c for a, c in zip(axes, centres))
        o = np.linalg.solve(A, b)
    z = sum(axes)
    z = z / np.linalg.norm(z)
    x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1), o


def common_fov(cameras: tuple[Camera, ...], B: np.ndarray, o: np.ndarray) -> np.ndarray:
    """Half extents (X−, X+, Y−, Y+) mm, along the rig's x and y axes through o, of the plane
    region every camera sees (found by bisection on each half axis)."""
    def seen(p):
        X = _world(B @ p + o, cameras[0])
        ok = True
        for c in cameras:
            uv, good = project(X, c)
            W, H = c.size
            ok &= bool(good) and -0.5 <= uv[0] <= W - 0.5 and -0.5 <= uv[1] <= H - 0.5
        return ok

    out = []
    for axis, sign in ((0, -1), (0, 1), (1, -1), (1, 1)):
        lo, hi = 0.0, 10.0 * float(np.linalg.norm(o))
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            p = np.zeros(3)
            p[axis] = sign * mid
            lo, hi = (mid, hi) if seen(p) else (lo, mid)
        out.append(lo)
    return np.array(out)


def _world(X_cam0: np.ndarray, cam1: Camera) -> np.ndarray:
    """Camera 0 frame → world."""
    return cam1.rotation.T @ (np.asarray(X_cam0, float) - cam1.translation)


def _tilt(angle: float, direction: float) -> np.ndarray:
    """Rotation by ``angle`` (deg) about the in-plane axis at ``direction`` (deg) from x."""
    a = math.radians(direction)
    return rodrigues(math.radians(angle) * np.array([math.cos(a), math.sin(a), 0.0]))


def _roll(angle: float) -> np.ndarray:
    return rodrigues([0.0, 0.0, math.radians(angle)])


def make_poses(cameras: tuple[Camera, ...], half_size: float, n: int, spec: PoseSpec = PoseSpec(),
               seed: int = 0, distance: float | None = None) -> list[Pose]:
    """``n`` poses of a target whose outer dots lie ``half_size`` mm from its centre.

    Same seed, same poses; pose i does not depend on ``n``. Pose i has kind
    ``spec.kinds[i % K]`` and, for the full FOV, cell ``(i + i // L) % CELLS²`` with
    L = lcm(K, CELLS²): any K consecutive poses hold every kind, any CELLS² consecutive ones
    (within a block of L) every cell, and every K·CELLS² poses every (kind, cell) pair once.
    """
    if n < 1:
        raise SceneError("pairs", f"must be ≥ 1, got {n}", "ask for at least one pose")
    B, o = rig_frame(cameras, distance)
    fov = common_fov(cameras, B, o)
    dist = float(np.linalg.norm(o))                      # camera 0 sits at the origin of its frame
    rng = np.random.default_rng(seed)
    K = len(spec.kinds)
    L = math.lcm(K, CELLS ** 2)
    poses = []
    for i in range(n):
        kind = spec.kinds[i % K]
        if spec.fov == "full":
            cell = (i + i // L) % CELLS ** 2
            # centre range: the outer dots reach spec.reach of the half FOV, cells split it evenly
            span = [max(e * spec.reach - half_size, 0.0) for e in fov]
            col, row = cell % CELLS, cell // CELLS
            u, v = (col + rng.random()) / CELLS, (row + rng.random()) / CELLS
            px = -span[0] + u * (span[0] + span[1])
            py = -span[2] + v * (span[2] + span[3])
        else:
            cell = -1
            px, py = (rng.uniform(-1, 1, 2) * spec.centre_fraction * np.array([fov[1], fov[3]]))
        roll = tilt = dz = 0.0
        direction = 0.0
        if kind in ("roll", "mixed"):
            roll = rng.uniform(-spec.roll, spec.roll)
        if kind in ("twist", "mixed"):
            tilt, direction = rng.uniform(*spec.tilt), rng.uniform(0.0, 360.0)
        if kind in ("plunge", "mixed"):
            dz = rng.uniform(-spec.plunge, spec.plunge) * dist
        R_rig = _tilt(tilt, direction) @ _roll(roll)
        R = B @ R_rig
        t = B @ np.array([px, py, dz]) + o
        poses.append(Pose(R=tuple(map(tuple, R)), t=tuple(t), kind=kind, cell=cell))
    return poses
