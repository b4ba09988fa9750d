"""Dot grids found and put in the target's order: cv2.findCirclesGrid with a SimpleBlobDetector
tuned to the image's grey levels finds and orders the whole grid (:func:`regular` rejects the
grids it reports for partly visible targets); where the image border cuts it, the markers
anchor the dots in view (:func:`find_partial_grid`); markers and handedness give the grid's
orientation (:func:`orient`); a dot off its neighbours' homography is rejected (:func:`inconsistent`)."""
from __future__ import annotations

import numpy as np

from glsim.workflows.calib.detection import to_gray8
from glsim.workflows.calib.targets import DotGrid

MARKER_TOLERANCE = 0.35  # |log(measured/expected area ratio)| below which a marker cell agrees
REGULARITY = 0.4       # largest second difference of a found grid, in grid spacings


def blob_detector(image: np.ndarray, white: bool):
    """A SimpleBlobDetector for ``image`` (float, [0, 1]): thresholds spread over the middle
    half between the two Otsu class means, so noisy dots do not fragment near either level."""
    import cv2
    img8 = to_gray8(image)
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
    marker cells show the markers' area ratio wins (|log(area / median area) − log(expected
    ratio)| summed over the marker cells: below MARKER_TOLERANCE per marker, and less than half
    the next turn's). Without markers the turn whose column
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
    cells = expected != 0                       # the marker cells: only they decide (noise elsewhere does not add up)
    ref = np.nanmedian(area)

    def misfit(perm):
        return np.nansum(np.abs(np.log(np.clip(area[perm][cells] / ref, 1e-6, None)) - expected[cells]))

    scores = sorted((misfit(perm), i) for i, (perm, _) in enumerate(candidates))
    best, i = scores[0]
    if best > MARKER_TOLERANCE * len(target.markers) or (len(scores) > 1 and scores[1][0] < 2 * best):
        return None
    return candidates[i][0]


def find_partial_grid(image: np.ndarray, target: DotGrid):
    """The dots in view when the grid is cut by the image border (or findCirclesGrid fails):
    ``(blobs, e_col, e_row)`` in the target's order, (N, 2) each, NaN where a dot was not found,
    or None. The markers anchor it: among the blobs of marker size, the three whose affine map
    from the marker cells predicts the most blobs of the cells around them (right-handed: the
    printed face) fix the labels; the grid then grows cell by cell, each predicted by an affine
    fit to the found cells within two cells and matched to the nearest blob within 0.3 of the
    local spacing. Needs the markers in view."""
    import itertools
    from scipy.spatial import cKDTree
    if not target.markers:
        return None
    detector, img8 = blob_detector(image, target.white_dots)
    kps = detector.detect(img8)
    if len(kps) < 6:
        return None
    P = np.array([k.pt for k in kps], np.float64)
    S = np.array([k.size for k in kps], np.float64)
    ratio = target.marker_diameter / target.dot_diameter
    cut = np.median(S) * (1 + ratio) / 2
    small = np.flatnonzero(S < cut if ratio < 1 else S > cut)
    if not 3 <= len(small) <= 12:
        return None
    rows, cols = target.rows, target.cols
    rc = np.stack(np.divmod(np.arange(rows * cols), cols), axis=1)            # (row, col) of every point
    design = np.c_[rc[:, 1], rc[:, 0], np.ones(len(rc))]                      # col, row, 1
    mk = np.array([r * cols + c for r, c in target.markers])
    near = np.flatnonzero(np.abs(rc[:, None, :] - rc[mk][None]).max(axis=2).min(axis=1) <= 2)
    tree = cKDTree(P)
    best = None
    for triple in itertools.permutations(small, 3):
        try:
            sol = np.linalg.solve(design[mk], P[list(triple)])                # (3, 2): e_col, e_row, origin
        except np.linalg.LinAlgError:
            continue
        e_col, e_row = sol[0], sol[1]
        spacing = min(np.linalg.norm(e_col), np.linalg.norm(e_row))
        if e_col[0] * e_row[1] - e_col[1] * e_row[0] <= 0 or spacing < 4:
            continue
        d, _ = tree.query(design[near] @ sol)
        score = int((d < 0.3 * spacing).sum())
        if best is None or score > best[0]:
            best = (score, sol)
    if best is None or best[0] < max(6, len(near) // 3):
        return None
    blobs = np.full((rows * cols, 2), np.nan)
    vec = np.full((rows * cols, 2, 2), np.nan)
    used = set()

    def local_affine(k):
        found = np.flatnonzero(~np.isnan(blobs[:, 0]))
        nb = found[np.abs(rc[found] - rc[k]).max(axis=1) <= 2]
        if len(nb) < 3 or np.linalg.matrix_rank(design[nb]) < 3:
            return None
        return np.linalg.lstsq(design[nb], blobs[nb], rcond=None)[0]

    def match(k, sol):
        e = np.linalg.norm(sol[:2], axis=1).min()
        d, j = tree.query(design[k] @ sol)
        if d < 0.3 * e and j not in used:
            blobs[k], vec[k] = P[j], sol[:2]
            used.add(j)
            return True
        return False

    for k in near:                                   # the cells around the markers, by the markers' map
        match(k, best[1])
    changed = True
    while changed:                                   # grow: each cell from the found cells around it
        changed = False
        todo = [k for k in range(rows * cols) if np.isnan(blobs[k, 0])]
        for k in sorted(todo, key=lambda k: np.abs(rc[k] - rc[mk]).max(axis=1).min()):
            sol = local_affine(k)
            if sol is not None and match(k, sol):
                changed = True
    for k in np.flatnonzero(~np.isnan(blobs[:, 0])):   # final local vectors from the grown grid
        sol = local_affine(k)
        if sol is not None:
            vec[k] = sol[:2]
    return blobs, vec[:, 0], vec[:, 1]


def inconsistent(points: np.ndarray, target: DotGrid) -> tuple[int, float] | None:
    """The dot farthest from where a homography fitted to its found neighbours (within two
    cells, itself left out) puts it, if farther than max(1 px, 0.05 × the local spacing):
    ``(index, distance px)``; None if every dot agrees. Lens distortion and perspective leave
    ≤ 0.7 px at 1624×1234; a wrongly matched dot is a spacing off."""
    import cv2
    rows, cols = target.rows, target.cols
    obj = target.points()[:, :2]
    rc = np.stack(np.divmod(np.arange(rows * cols), cols), axis=1)
    found = np.flatnonzero(~np.isnan(points[:, 0]))
    worst = None
    for k in found:
        nb = found[(np.abs(rc[found] - rc[k]).max(axis=1) <= 2) & (found != k)]
        if len(nb) < 6:
            continue
        H, _ = cv2.findHomography(obj[nb], points[nb], 0)
        if H is None:
            continue
        pred = cv2.perspectiveTransform(obj[k].reshape(1, 1, 2), H).ravel()
        d = float(np.linalg.norm(pred - points[k]))
        spacing = np.median(np.linalg.norm(points[nb] - points[k], axis=1) /
                            np.linalg.norm(obj[nb] - obj[k], axis=1)) * target.pitch
        if d > max(1.0, 0.05 * spacing) and (worst is None or d > worst[1]):
            worst = (int(k), d)
    return worst
