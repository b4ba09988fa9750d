"""What the preview's overlays show, each as a plain function of the rendered images, their
ground truth and the scene (numpy / OpenCV, no GL), so that tests can hold each against its
definition."""
from __future__ import annotations

import math

import cv2
import numpy as np

from glsim.effects import dof
from glsim.scene import Optics
from glsim.scene.camera import Camera, project, to_camera
from glsim.scene.speckle import speckle_stats


def world_from_cam1(X: np.ndarray, cam1: Camera) -> np.ndarray:
    """Points in camera 1's frame (as the truth gives them) → world (mm)."""
    return (np.asarray(X, float) - cam1.translation) @ cam1.rotation


def displacement(truth, component: str = "magnitude") -> np.ndarray:
    """Ground-truth displacement (mm) per pixel: |X_deformed − X_undeformed| or one of its
    components x, y, z in camera 1's frame; NaN off the specimen."""
    d = truth.X_deformed - truth.X_undeformed
    if component == "magnitude":
        return np.linalg.norm(d, axis=-1)
    return d[..., "xyz".index(component)]


def mm_per_px(cam: Camera, X_world: np.ndarray) -> float:
    """Mean scale (mm per pixel) of ``cam`` over the points ``X_world`` (N, 3)."""
    z = to_camera(X_world, cam)[:, 2]
    return float(np.mean(z) / math.sqrt(cam.fx * cam.fy))


def overlap(truth_a, truth_b, cam_a: Camera, cam_b: Camera, cam1: Camera, tolerance_px: float = 2.0) -> np.ndarray:
    """Pixels of camera A whose material point camera B sees too: the deformed point of each
    covered pixel of A, projected into B, lands on a covered pixel of B (nearest) whose own
    deformed point lies within ``tolerance_px`` of B's pixels (at that depth) of it — which
    rules out points B sees hidden behind another part of the specimen."""
    out = np.zeros(truth_a.mask.shape, bool)
    rows, cols = np.nonzero(truth_a.mask)
    if rows.size == 0:
        return out
    Xw = world_from_cam1(truth_a.X_deformed[rows, cols], cam1)
    uv, ok = project(Xw, cam_b)
    Wb, Hb = cam_b.size
    u, v = np.rint(uv[:, 0]).astype(np.int64), np.rint(uv[:, 1]).astype(np.int64)
    ok &= (u >= 0) & (u < Wb) & (v >= 0) & (v < Hb)
    u, v = np.where(ok, u, 0), np.where(ok, v, 0)
    ok &= truth_b.mask[v, u]
    Xb = world_from_cam1(truth_b.X_deformed[v, u], cam1)
    z = to_camera(Xw, cam_b)[:, 2]
    tol = tolerance_px * z / math.sqrt(cam_b.fx * cam_b.fy)
    with np.errstate(invalid="ignore"):
        ok &= np.linalg.norm(Xb - Xw, axis=1) <= tol
    out[rows, cols] = ok
    return out


def depth(truth, cam: Camera, cam1: Camera) -> np.ndarray:
    """Camera-frame depth Z (mm) of each pixel's deformed material point; NaN off the specimen."""
    return to_camera(world_from_cam1(truth.X_deformed, cam1), cam)[..., 2]


def coc_map(truth, cam: Camera, cam1: Camera, optics: Optics) -> np.ndarray:
    """Circle of confusion (px of the full-size camera, eq. 19 as the renderer evaluates it)
    of each pixel's surface point; NaN off the specimen."""
    Z = depth(truth, cam, cam1)
    with np.errstate(invalid="ignore"):
        return np.where(truth.mask, dof.coc_px(np.where(truth.mask, Z, 2 * optics.focal_length + 1), optics), np.nan)


def dof_limits(optics: Optics) -> tuple[float, float]:
    """Near and far distance (mm, along the axis) between which CoC ≤ ``coc_px`` (eq. 19
    solved exactly; far = inf beyond the hyperfocal distance)."""
    f, N, D = optics.focal_length, optics.f_number, optics.focus_distance
    c = optics.coc_px * optics.pixel_pitch
    near = D * f * (f + c * N) / (f * f + c * N * D)
    den = f * f - c * N * D
    far = D * f * (f - c * N) / den if den > 0 else math.inf
    return near, far


def clipped(image: np.ndarray, covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(above full scale, below zero): the specimen's pixels (``covered``) that clip when
    quantised; the background is not counted."""
    return (image > 1.0) & covered, (image < 0.0) & covered


def node_displacement_px(cam: Camera, nodes: np.ndarray, deformed: np.ndarray) -> np.ndarray:
    """Image displacement (px) of each mesh node in ``cam``, |π(deformed) − π(undeformed)|; NaN
    for a node outside the image (or not projectable) in either state."""
    W, H = cam.size
    a, oka = project(nodes, cam)
    b, okb = project(deformed, cam)
    inside = oka & okb
    for uv in (a, b):
        inside &= (uv[:, 0] >= -0.5) & (uv[:, 0] <= W - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= H - 0.5)
    return np.where(inside, np.linalg.norm(b - a, axis=1), np.nan)


def displacement_range(cam: Camera, nodes: np.ndarray, deformed: np.ndarray) -> tuple[float, float]:
    """Smallest and largest image displacement (px) of the nodes ``cam`` sees at this step."""
    d = node_displacement_px(cam, nodes, deformed)
    d = d[np.isfinite(d)]
    return (float(d.min()), float(d.max())) if d.size else (math.nan, math.nan)


def edge_polylines(cam: Camera, deformed: np.ndarray, quads: np.ndarray, samples: int = 8) -> list[np.ndarray]:
    """The deformed mesh's element edges projected into ``cam`` (with its distortion), each a
    polyline (k, 2) of pixel coordinates sampled ``samples`` times along the straight edge."""
    edges = np.concatenate([quads[:, [0, 1]], quads[:, [1, 2]], quads[:, [2, 3]], quads[:, [3, 0]]])
    edges = edges[edges[:, 0] != edges[:, 1]]
    edges = np.unique(np.sort(edges, axis=1), axis=0)
    t = np.linspace(0.0, 1.0, samples + 1)[None, :, None]
    P = deformed[edges[:, 0]][:, None] * (1 - t) + deformed[edges[:, 1]][:, None] * t
    uv, ok = project(P.reshape(-1, 3), cam)
    uv, ok = uv.reshape(P.shape[0], -1, 2), ok.reshape(P.shape[0], -1)
    return [uv[i] for i in range(len(uv)) if ok[i].all()]


def speckle_region(mask: np.ndarray, margin: int = 3) -> tuple[int, int, int, int] | None:
    """The largest square (row0, row1, col0, col1; ends exclusive) inside ``mask`` around its
    most interior pixel, ``margin`` px in from the edge; None when it would be under 16 px."""
    if not mask.any():
        return None
    dist = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    r, c = np.unravel_index(int(np.argmax(dist)), dist.shape)
    half = int(dist[r, c] / math.sqrt(2)) - margin
    if half < 8:
        return None
    return r - half, r + half, c - half, c + half


def speckle_size(image: np.ndarray, mask: np.ndarray) -> dict | None:
    """:func:`glsim.scene.speckle.speckle_stats` of the image inside :func:`speckle_region`,
    with the region; None where the specimen shows too little."""
    box = speckle_region(mask)
    if box is None:
        return None
    r0, r1, c0, c1 = box
    stats = speckle_stats(image[r0:r1, c0:c1])
    stats["region"] = box
    return stats


def colour_map(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Values → RGB uint8 with the viridis map over [lo, hi] (NaN → black)."""
    span = hi - lo if hi > lo else 1.0
    x = np.clip((np.nan_to_num(values, nan=lo) - lo) / span, 0, 1)
    rgb = cv2.applyColorMap(np.rint(x * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1]
    return np.ascontiguousarray(rgb)


def nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """About ``n`` round tick values within [lo, hi]."""
    if not hi > lo:
        return np.array([lo])
    raw = (hi - lo) / max(n - 1, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = min((m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw), default=10 * mag)
    return np.arange(math.ceil(lo / step) * step, hi + step * 1e-9, step)
