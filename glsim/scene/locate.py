"""Which element a camera-0 pixel's ray meets, and where: the ray-cast point locator behind a truth
file's ``at(points)`` and ``glsim compare``. Bilinear Q4 elements, or a quadratic mesh's patches;
``g`` is any geometry with ``nodes``, ``quads``, ``patches`` and ``deformed(step)`` (a library's
geometry file, or :func:`glsim.io.truth.mesh_geometry` of a mesh). Camera 0's frame, mm."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from glsim.scene import quadratic as qd
from glsim.scene.bilinear import bilinear, intersect_ray_patch
from glsim.scene.camera import Camera, pixel_to_normalized, project_camera_frame, to_camera, undistort
from glsim.scene.optional import rigid_state


@dataclass(frozen=True, eq=False)
class PointTruth:
    """Ground truth at given camera-0 pixel coordinates of the reference state (camera 0's
    frame, mm): ``valid`` where the pixel's ray meets the specimen; NaN elsewhere."""
    points: np.ndarray
    valid: np.ndarray
    element: np.ndarray
    xi: np.ndarray
    eta: np.ndarray
    X_undeformed: np.ndarray
    X_deformed: np.ndarray
    step: int

    @property
    def displacement(self) -> np.ndarray:
        return self.X_deformed - self.X_undeformed


ROW_ITERATIONS = 8   # a rolling shutter's row of a point (CompactTruth.at): fixed-point steps at most


def rows_at(pt: PointTruth, g, cam: Camera, cam0: Camera, velocity, omega, centre,
            taus: np.ndarray) -> PointTruth:
    """``pt`` (at its step's state) with each valid point's deformed position in the state of
    the row of ``cam``'s rolling-shutter image where it is seen — a rigid motion
    (:func:`~glsim.scene.optional.rigid_state`; the rows' times ``taus`` (H,) s): the row r nearest
    its projection, found by fixed-point iteration (r → the point at row r's time → its row; at
    most ROW_ITERATIONS, stopping when r repeats), rows outside the image clipped to its first or
    last. Camera 0's frame, mm."""
    shape, points = element_evaluator(g, pt.element[pt.valid])
    X = shape(points(g.deformed(pt.step)), pt.xi[pt.valid], pt.eta[pt.valid])   # world, the step's state
    row = np.full(len(X), (len(taus) - 1) // 2)
    for _ in range(ROW_ITERATIONS):
        moved = np.empty_like(X)
        for r in np.unique(row):
            moved[row == r] = rigid_state(X[row == r], taus[r], velocity, omega, centre)
        new = np.clip(np.rint(project_camera_frame(to_camera(moved, cam), cam)[0][:, 1]), 0, len(taus) - 1)
        if np.array_equal(new, row):
            break
        row = new.astype(np.int64)
    Xd = pt.X_deformed.copy()
    Xd[pt.valid] = to_camera(moved, cam0)
    return dataclasses.replace(pt, X_deformed=Xd)


def points_truth(g, cam0: Camera, points, step: int) -> PointTruth:
    """See :meth:`CompactTruth.at`; bilinear Q4 elements, or a quadratic mesh's patches
    (``g.patches``: the ray met by Newton on the curved patch, :func:`glsim.scene.quadratic.intersect_ray`,
    as the oracle's exact mode)."""
    pts = np.asarray(points, np.float64).reshape(-1, 2)
    n = len(pts)
    xn, ray_ok = undistort(pixel_to_normalized(pts, cam0.intrinsics), cam0.distortion.coeffs)
    if g.patches is None:
        P = to_camera(g.nodes, cam0)[g.quads]                        # (M, 4, 3) camera-0 frame
        lo, hi = _quad_boxes(P)
        intersect = intersect_ray_patch
    else:
        P = qd.patch_points(g.patches, to_camera(g.nodes, cam0))   # (M, 9, 3)
        lo, hi = _patch_boxes(P)
        intersect = qd.intersect_ray
    pe, pp = _candidates(lo, hi, xn, ray_ok)
    best_e = np.full(n, -1, np.int64)
    best_xi, best_eta = np.full(n, np.nan), np.full(n, np.nan)
    if len(pe):
        xi, eta, z, ok = intersect(P[pe], xn[pp])
        k = np.flatnonzero(ok)
        order = k[np.lexsort((pe[k], z[k], pp[k]))]                   # per point: nearest, then lowest index
        first = order[np.unique(pp[order], return_index=True)[1]]
        best_e[pp[first]] = pe[first]
        best_xi[pp[first]], best_eta[pp[first]] = xi[first], eta[first]
    valid = best_e >= 0
    xi, eta = best_xi[valid], best_eta[valid]
    shape, points = element_evaluator(g, best_e[valid])
    Xu = np.full((n, 3), np.nan)
    Xd = np.full((n, 3), np.nan)
    Xu[valid] = to_camera(shape(points(g.nodes), xi, eta), cam0)
    Xd[valid] = to_camera(shape(points(g.deformed(step)), xi, eta), cam0)
    return PointTruth(points=pts, valid=valid, element=best_e, xi=best_xi, eta=best_eta,
                      X_undeformed=Xu, X_deformed=Xd, step=step)


def element_evaluator(g, e: np.ndarray):
    """How positions on the elements ``e`` are evaluated: (shape, points) — ``shape(P, ξ, η)``
    (bilinear, or a quadratic mesh's patches' shape functions) over ``points(X)``, the
    elements' corners or control points from the per-node values X (N, D)."""
    return (bilinear if g.patches is None else qd.evaluate), lambda X: qd.element_points(g.quads, g.patches, e, X)


def _quad_boxes(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each Q4 element's box in normalized coordinates (lo, hi (M, 2)): its corners'
    projections (a bilinear patch lies in its corners' hull), padded by 1e-9 relative; an
    element crossing the camera plane gets an infinite one (always a candidate)."""
    front = (P[..., 2] > 0).all(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        proj = P[..., :2] / np.where(front[:, None], P[..., 2], 1.0)[..., None]
    return _padded(proj.min(axis=1), proj.max(axis=1), np.abs(proj).max(axis=1), front)


def _patch_boxes(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each patch's box in normalized coordinates (lo, hi (M, 2)): the projections of the
    corners of a 3-D box that holds its surface (:func:`glsim.scene.quadratic.surface_box`;
    x/Z and y/Z over a box in front of the camera are extreme at its corners), padded as
    :func:`_quad_boxes`; a box reaching the camera plane gives an infinite one."""
    lo3, hi3 = qd.surface_box(P)
    front = lo3[:, 2] > 0
    z = np.where(front, 1.0, np.nan)[:, None] * np.stack([lo3[:, 2], hi3[:, 2]], 1)     # (M, 2)
    proj = np.stack([np.concatenate([lo3[:, k:k + 1] / z, hi3[:, k:k + 1] / z], 1) for k in (0, 1)], -1)   # (M, 4, 2)
    return _padded(proj.min(axis=1), proj.max(axis=1), np.abs(proj).max(axis=1), front)


def _padded(lo, hi, size, front):
    pad = 1e-9 * (1.0 + size)
    lo, hi = lo - pad, hi + pad
    lo[~front], hi[~front] = -np.inf, np.inf
    return lo, hi


def _candidates(lo, hi, xn, ok, cells: int = 64):
    """(element, point) pairs whose element box (normalized coordinates) holds the point,
    through a uniform grid of cells over the points' extent."""
    pts = np.flatnonzero(ok)
    if not len(pts) or not len(lo):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    x = xn[pts]
    x0, x1 = x.min(axis=0), x.max(axis=0)
    span = np.maximum(x1 - x0, 1e-12)
    cell = lambda v: np.clip(np.floor((v - x0) / span * cells), 0, cells - 1).astype(np.int64)  # noqa: E731
    inside = (hi >= x0).all(axis=1) & (lo <= x1).all(axis=1)
    els = np.flatnonzero(inside)
    c0, c1 = cell(np.maximum(lo[els], x0)), cell(np.minimum(hi[els], x1))
    nx, ny = c1[:, 0] - c0[:, 0] + 1, c1[:, 1] - c0[:, 1] + 1
    cnt = nx * ny
    e = np.repeat(els, cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    ex = np.repeat(c0[:, 0], cnt) + local % np.repeat(nx, cnt)
    ey = np.repeat(c0[:, 1], cnt) + local // np.repeat(nx, cnt)
    ecell = ey * cells + ex
    pc = cell(x)
    pcell = pc[:, 1] * cells + pc[:, 0]
    order = np.argsort(ecell, kind="stable")
    ecell, e = ecell[order], e[order]
    start = np.searchsorted(ecell, pcell, "left")
    stop = np.searchsorted(ecell, pcell, "right")
    cnt = stop - start
    p = np.repeat(pts, cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    pe = e[np.repeat(start, cnt) + local]
    keep = ((xn[p] >= lo[pe]) & (xn[p] <= hi[pe])).all(axis=1)
    return pe[keep], p[keep]
