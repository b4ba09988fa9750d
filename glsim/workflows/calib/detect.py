"""Dot-grid detection: cv2.findCirclesGrid with a SimpleBlobDetector tuned to the image's grey
levels, then a grey-level centroid of every dot in a window of ±``window`` × the local grid
spacing, and the grid's orientation from its handedness and marker dots.

The centroid is Σ(I − b)·p / Σ(I − b) over the window (b: median grey of the window's outer
ring; the sign flipped for dark dots), iterated with the window re-centred. The window is the
parallelogram spanned by the local grid vectors, so it follows the perspective of the view.
Without noise or blur it measures the area centroid of the dot's image, not the projection
of its centre (they differ by the perspective bias, design-notes.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glsim.errors import SceneError
from glsim.workflows.calib.targets import DotGrid

WINDOW = 0.45          # half-width of the centroid window, in local grid spacings
ITERATIONS = 4         # centroid passes, each re-centring the window
MARKER_TOLERANCE = 0.35  # |log(measured/expected area ratio)| below which a marker cell agrees
REGULARITY = 0.4       # largest second difference of a found grid, in grid spacings


@dataclass(frozen=True, eq=False)
class Detection:
    """Dots found in one image, in the target's point order (row-major).

    ``points`` (N, 2) px: refined centres, NaN where a dot's window left the image;
    ``blobs`` (N, 2) px: findCirclesGrid's blob centres, same order; ``ok`` (N,) bool.
    """
    points: np.ndarray
    blobs: np.ndarray
    ok: np.ndarray


def to_unit(image: np.ndarray, bit_depth: int | None = None) -> np.ndarray:
    """An image as float64 grey levels in [0, 1] of full scale: floats are kept, integers
    divided by 2^bit_depth − 1 (default: 8 for uint8, 16 otherwise)."""
    image = np.asarray(image)
    if image.ndim != 2:
        raise SceneError("image", f"shape {image.shape} is not (H, W)", "give a greyscale image")
    if np.issubdtype(image.dtype, np.floating):
        return image.astype(np.float64)
    bits = bit_depth or (8 if image.dtype == np.uint8 else 16)
    return image.astype(np.float64) / ((1 << bits) - 1)


def blob_detector(image: np.ndarray, white: bool):
    """A SimpleBlobDetector for ``image`` (float, [0, 1]): thresholds spread over the middle
    half between the two Otsu class means, so noisy dots do not fragment near either level."""
    import cv2
    img8 = np.clip(np.rint(image * 255), 0, 255).astype(np.uint8)
    t, _ = cv2.threshold(img8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    lo, hi = img8[img8 <= t].mean(), img8[img8 > t].mean() if np.any(img8 > t) else 255.0
    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold = float(lo + 0.25 * (hi - lo)), float(lo + 0.75 * (hi - lo))
    p.thresholdStep = max((p.maxThreshold - p.minThreshold) / 6, 1.0)
    p.minRepeatability = 2
    p.filterByColor, p.blobColor = True, 255 if white else 0
    p.filterByArea, p.minArea, p.maxArea = True, 4.0, image.size / 20
    p.filterByCircularity, p.minCircularity = True, 0.5
    p.filterByInertia, p.minInertiaRatio = True, 0.15
    p.filterByConvexity, p.minConvexity = True, 0.85
    p.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(p), img8


def find_grid(image: np.ndarray, target: DotGrid) -> np.ndarray | None:
    """findCirclesGrid's centres (rows·cols, 2) in its own order, or None."""
    import cv2
    detector, img8 = blob_detector(image, target.white_dots)
    for flags in (cv2.CALIB_CB_SYMMETRIC_GRID, cv2.CALIB_CB_SYMMETRIC_GRID | cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(img8, (target.cols, target.rows), flags=flags, blobDetector=detector)
        if found:
            return centres.reshape(-1, 2).astype(np.float64)
    return None


def regular(points: np.ndarray, rows: int, cols: int, tol: float = REGULARITY) -> bool:
    """Whether the grid is smooth: every second difference along rows and columns is below
    ``tol`` × the median spacing (perspective and lens distortion give a few %). It rejects
    the grids findCirclesGrid reports for partly visible targets with repeated points."""
    g = points.reshape(rows, cols, 2)
    spacing = np.median(np.concatenate([np.linalg.norm(np.diff(g, axis=a), axis=-1).ravel() for a in (0, 1)]))
    second = [np.linalg.norm(np.diff(g, 2, axis=a), axis=-1) for a in (0, 1)]
    return bool(spacing > 0 and max(float(d.max()) for d in second) < tol * spacing)


def grid_vectors(points: np.ndarray, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Local image vectors (N, 2) to the next column and the next row of each grid point
    (central differences inside, one-sided at the border)."""
    g = points.reshape(rows, cols, 2)
    return (np.gradient(g, axis=1).reshape(-1, 2), np.gradient(g, axis=0).reshape(-1, 2))


def centroid(image: np.ndarray, centre, e_col, e_row, white: bool, ring: float,
             window: float = WINDOW) -> tuple[np.ndarray, float] | None:
    """One grey-level centroid pass (see the module text): ``(centre, mass)`` with mass =
    Σ(I − b) in grey × px², or None if the window leaves the image.

    ``ring``: inner edge of the background ring, in grid spacings (outside every dot).
    """
    A = np.stack([e_col, e_row], axis=1)
    if not abs(np.linalg.det(A)) > 1e-6:
        return None
    corners = centre + (A @ np.array([[-1, -1, 1, 1], [-1, 1, -1, 1]]) * window).T
    u0, v0 = np.floor(corners.min(0)).astype(int)
    u1, v1 = np.ceil(corners.max(0)).astype(int)
    H, W = image.shape
    if u0 < 0 or v0 < 0 or u1 >= W or v1 >= H:
        return None
    uu, vv = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
    p = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    ab = np.linalg.solve(A, (p - centre).T).T
    m = np.abs(ab).max(axis=1)
    I = image[v0:v1 + 1, u0:u1 + 1].ravel()
    inside = m <= window
    bg = np.median(I[inside & (m >= ring)])
    w = (I - bg if white else bg - I)[inside]
    mass = w.sum()
    if not mass > 0:
        return None
    return (w @ p[inside]) / mass, float(mass)


def refine(image: np.ndarray, points: np.ndarray, target: DotGrid, window: float = WINDOW):
    """Grey-level centroids of all dots: ``(points, area)`` where area (N,) is each dot's
    mass over its local grid cell area (≈ (dot area / pitch²)·contrast); NaN where lost."""
    e_col, e_row = grid_vectors(points, target.rows, target.cols)
    ring = (float(np.max(target.diameters())) / 2 / target.pitch + window) / 2   # between dots and edge
    out = np.full_like(points, np.nan)
    area = np.full(len(points), np.nan)
    for k, c in enumerate(points):
        cell = abs(e_col[k, 0] * e_row[k, 1] - e_col[k, 1] * e_row[k, 0])
        for _ in range(ITERATIONS):
            r = centroid(image, c, e_col[k], e_row[k], target.white_dots, ring, window)
            if r is None:
                break
            c, mass = r
        else:
            out[k], area[k] = c, mass / cell
    return out, area


def grid_permutations(rows: int, cols: int) -> list[np.ndarray]:
    """Every re-numbering of a rows × cols grid that keeps its shape (rotations and mirrors)."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    out = [idx, idx[::-1], idx[:, ::-1], idx[::-1, ::-1]]
    if rows == cols:
        out += [g.T for g in out]
    return [g.ravel() for g in out]


def orient(points: np.ndarray, area: np.ndarray, target: DotGrid) -> np.ndarray | None:
    """The permutation that puts detected points into the target's order, or None if the
    markers do not say which.

    Mirror orderings are excluded by the handedness a camera sees the printed face with
    (columns × rows turning clockwise in the image); among the remaining turns, the one whose
    marker cells show the markers' area ratio wins. Without markers the turn whose column
    direction points most to the image's right is chosen (consistent between the cameras of a
    rig as long as the target is not rolled near ±45°/90°)."""
    rows, cols = target.rows, target.cols
    candidates = []
    for perm in grid_permutations(rows, cols):
        p = points[perm].reshape(rows, cols, 2)
        e_col = np.nanmean(p[:, 1:] - p[:, :-1], axis=(0, 1))
        e_row = np.nanmean(p[1:] - p[:-1], axis=(0, 1))
        if e_col[0] * e_row[1] - e_col[1] * e_row[0] > 0:
            candidates.append((perm, e_col))
    if not target.markers:
        return max(candidates, key=lambda c: c[1][0] / np.linalg.norm(c[1]))[0]
    expected = np.log((target.diameters() / target.dot_diameter) ** 2)
    ref = np.nanmedian(area)

    def misfit(perm):
        return np.nansum(np.abs(np.log(np.clip(area[perm] / ref, 1e-6, None)) - expected))

    scores = sorted((misfit(perm), i) for i, (perm, _) in enumerate(candidates))
    best, i = scores[0]
    if best > MARKER_TOLERANCE * len(target.markers) or (len(scores) > 1 and scores[1][0] < 2 * best):
        return None
    return candidates[i][0]


def detect_dots(image: np.ndarray, target: DotGrid, bit_depth: int | None = None,
                min_points: int | None = None, window: float = WINDOW) -> Detection | None:
    """Detect ``target`` in ``image``; None if the grid is not found or not :func:`regular`,
    its orientation is ambiguous, or fewer than ``min_points`` (default: all) dots could be
    refined."""
    img = to_unit(image, bit_depth)
    blobs = find_grid(img, target)
    if blobs is None or not regular(blobs, target.rows, target.cols):
        return None
    points, area = refine(img, blobs, target, window)
    perm = orient(np.where(np.isnan(points), blobs, points), area, target)
    if perm is None:
        return None
    points, blobs = points[perm], blobs[perm]
    ok = ~np.isnan(points[:, 0])
    if ok.sum() < (target.n_points if min_points is None else min_points):
        return None
    return Detection(points=points, blobs=blobs, ok=ok)
