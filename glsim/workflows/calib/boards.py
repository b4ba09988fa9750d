"""Chessboards and ChArUco boards: OpenCV's detectors, corners put in the target's order (and
ChArUco corners refined on the smoothed image)."""
from __future__ import annotations

import numpy as np

from glsim.workflows.calib.detection import Detection, to_gray8, to_unit
from glsim.workflows.calib.dotgrid import grid_permutations
from glsim.workflows.calib.targets import Charuco, Chessboard

CHARUCO_MIN_GAP_PX = 8.0     # below this marker-to-corner gap OpenCV's corners are kept


def orient_chessboard(image: np.ndarray, corners: np.ndarray, target: Chessboard) -> np.ndarray | None:
    """The permutation that puts findChessboardCorners' corners (R × C inner corners in its own
    order) into the target's row-major order, or None if the board's squares do not say which.

    Mirrors are excluded by handedness (as for dots); among the turns, the one whose squares
    are dark where the board's are (the top-left square is dark) wins by the grey levels at the
    square centres. A board with rows + cols even looks the same after a half turn: None."""
    from scipy.ndimage import map_coordinates
    R, C = target.rows - 1, target.cols - 1
    best = []
    for perm in grid_permutations(R, C):
        g = corners[perm].reshape(R, C, 2)
        e_col, e_row = (g[:, 1:] - g[:, :-1]).mean(axis=(0, 1)), (g[1:] - g[:-1]).mean(axis=(0, 1))
        if e_col[0] * e_row[1] - e_col[1] * e_row[0] <= 0:
            continue
        centres = (g[:-1, :-1] + g[:-1, 1:] + g[1:, :-1] + g[1:, 1:]) / 4          # square (i + 1, j + 1)
        grey = map_coordinates(image, [centres[..., 1].ravel(), centres[..., 0].ravel()], order=1).reshape(R - 1, C - 1)
        i, j = np.indices(grey.shape)
        dark = (i + j) % 2 == 0
        best.append((float(grey[~dark].mean() - grey[dark].mean()), perm))
    if not best:
        return None
    best.sort(key=lambda x: -x[0])
    contrast = abs(target.light_grey - target.dark_grey)
    if best[0][0] < 0.5 * contrast or (len(best) > 1 and best[1][0] > 0.5 * contrast):
        return None
    return best[0][1]


def detect_chessboard(image: np.ndarray, target: Chessboard, bit_depth: int | None = None,
                      min_points: int | None = None, explain: bool = False):
    """Inner corners of ``target`` by cv2.findChessboardCornersSB (exhaustive, sub-pixel
    accuracy), in the target's order (:func:`orient_chessboard`); None if not found or its
    orientation is ambiguous. OpenCV needs every corner in view. ``explain``: as detect_dots."""
    import cv2
    img = to_unit(image, bit_depth)
    R, C = target.rows - 1, target.cols - 1
    found, corners = cv2.findChessboardCornersSB(to_gray8(img), (C, R),
                                                 flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    if not found:
        return (None, "findChessboardCornersSB found no board (it needs every corner in view)") if explain else None
    pts = corners.reshape(-1, 2).astype(np.float64)
    perm = orient_chessboard(img, pts, target)
    if perm is None:
        return (None, "the squares do not tell the board's orientation") if explain else None
    pts = pts[perm]
    d = Detection(points=pts, blobs=pts.copy(), ok=np.ones(len(pts), bool))
    return (d, "") if explain else d


def detect_charuco(image: np.ndarray, target: Charuco, bit_depth: int | None = None,
                   min_points: int | None = None, explain: bool = False):
    """ChArUco corners by cv2.aruco.CharucoDetector (markers identify the corners, so a part of
    the board is enough), in the target's order (OpenCV's corner ids); NaN for corners not
    found. None if fewer than ``min_points`` (default 4) are."""
    import cv2
    img = to_unit(image, bit_depth)
    corners, ids, _, _ = cv2.aruco.CharucoDetector(target.board()).detectBoard(to_gray8(img))
    n = len(target.points())
    need = max(min_points or 4, 4)
    if ids is None or len(ids) < need:
        why = f"CharucoDetector found {0 if ids is None else len(ids)} corners, {need} needed"
        return (None, why) if explain else None
    pts = np.full((n, 2), np.nan)
    pts[ids.ravel()] = refine_charuco_corners(img, corners.reshape(-1, 2).astype(np.float64), target)
    d = Detection(points=pts, blobs=pts.copy(), ok=~np.isnan(pts[:, 0]))
    return (d, "") if explain else d


def refine_charuco_corners(image: np.ndarray, corners: np.ndarray, target: Charuco) -> np.ndarray:
    """CharucoDetector's corners (N, 2) px refined by cv2.cornerSubPix on the image smoothed
    with a Gaussian, in a window that stays inside the marker-free cross round each corner.

    The window's half-width is half the gap between a corner and the nearest marker (from the
    median spacing of the corners and the board's marker/square ratio) and σ half of that:
    smoothing makes the saddle's grey levels differentiable, which the aliased edges of a
    rendered (or printed and imaged) board are not. Where the gap is under
    CHARUCO_MIN_GAP_PX, or a corner moves by more than a quarter of the window, OpenCV's
    corner is kept. Measured on noise-free 1624×1234 boards (63 px squares): 0.016 px mean,
    0.045 max against the projected corners, OpenCV's 0.067 / 0.22 (docs/calib.md)."""
    import cv2
    if len(corners) < 2:
        return corners
    d = np.linalg.norm(corners[:, None] - corners[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    gap = float(np.median(d.min(axis=1))) * (target.square - target.marker) / (2 * target.square)
    if gap < CHARUCO_MIN_GAP_PX:
        return corners
    w = int(round(0.5 * gap))
    smooth = cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), 0.5 * w)
    p = corners.astype(np.float32).reshape(-1, 1, 2).copy()
    cv2.cornerSubPix(smooth, p, (w, w), (-1, -1), (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 200, 1e-5))
    p = p.reshape(-1, 2).astype(np.float64)
    moved = np.linalg.norm(p - corners, axis=1) > 0.25 * w
    p[moved] = corners[moved]
    return p
