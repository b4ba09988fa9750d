"""Target detection, the entry points :func:`detect_target` and :func:`detect_dots`.

Dot grids: :mod:`~glsim.workflows.calib.dotgrid` finds and orders the grid (cv2.findCirclesGrid
with a SimpleBlobDetector tuned to the image's grey levels, or, where the image border cuts it,
the markers anchoring the dots in view), markers and handedness give its orientation;
:mod:`~glsim.workflows.calib.dotcentres` measures every dot's centre, by default by the model
fit to the grey levels near its edge of :mod:`~glsim.workflows.calib.dotfit` (at the
Cramér–Rao bound of the image); a grid with a dot off its neighbours' homography is rejected.
Chessboards and ChArUco boards: OpenCV's detectors, corners put in the target's order
(:mod:`~glsim.workflows.calib.boards`). Every detector reads the image as grey levels of full
scale and returns a :class:`~glsim.workflows.calib.detection.Detection`.
"""
from __future__ import annotations

import numpy as np

from glsim.errors import SceneError
from glsim.workflows.calib.boards import detect_charuco, detect_chessboard
from glsim.workflows.calib.detection import Detection, to_unit
from glsim.workflows.calib.dotcentres import refine
from glsim.workflows.calib.dotgrid import find_grid, find_partial_grid, inconsistent, orient, regular
from glsim.workflows.calib.targets import Charuco, Chessboard, DotGrid

VERSION = 4            # of the detector's results (detection caches made by another version are not used)


def detect_dots(image: np.ndarray, target: DotGrid, bit_depth: int | None = None,
                min_points: int | None = None, method: str = "fit", explain: bool = False):
    """Detect ``target`` in ``image``: a :class:`Detection`, or None if the grid is found
    neither whole (findCirclesGrid, :func:`regular`) nor in part (:func:`find_partial_grid`, by
    the markers), its orientation is ambiguous, a dot disagrees with its neighbours
    (:func:`inconsistent`), or fewer than ``min_points`` (default: all) dots could be refined.
    ``explain``: return ``(Detection | None, reason)``, the reason "" when found."""
    def out(d, reason):
        return (d, reason) if explain else d
    img = to_unit(image, bit_depth)
    need = target.n_points if min_points is None else min_points
    blobs = find_grid(img, target)
    if blobs is not None and regular(blobs, target.rows, target.cols):
        points, area = refine(img, blobs, target, method)
        perm = orient(np.where(np.isnan(points), blobs, points), area, target)
        if perm is None:
            return out(None, "the markers do not tell the grid's orientation")
        points, blobs = points[perm], blobs[perm]
    else:
        partial = find_partial_grid(img, target)
        if partial is None:
            return out(None, "no grid found (whole, or in part around the markers)")
        blobs, e_col, e_row = partial
        if (~np.isnan(blobs[:, 0])).sum() < need:
            return out(None, f"only {(~np.isnan(blobs[:, 0])).sum()} dots found in view, {need} needed")
        points, area = refine(img, blobs, target, method, vectors=(e_col, e_row))
    bad = inconsistent(points, target)
    if bad is not None:
        r, c = divmod(bad[0], target.cols)
        return out(None, f"dot (row {r}, col {c}) lies {bad[1]:.1f} px from where its neighbours put it "
                         "(a homography fit): the grid is rejected")
    ok = ~np.isnan(points[:, 0])
    if ok.sum() < need:
        return out(None, f"only {ok.sum()} dots measured, {need} needed")
    return out(Detection(points=points, blobs=blobs, ok=ok), "")


def default_method(target) -> str:
    """The detector used for ``target``: the model fit for dot grids, OpenCV's for boards."""
    if isinstance(target, DotGrid):
        return "fit"
    if isinstance(target, Chessboard):
        return "chessboard"
    if isinstance(target, Charuco):
        return "charuco"
    raise SceneError("target", f"{type(target).__name__} cannot be detected", "use DotGrid, Chessboard or Charuco")


def detect_target(image: np.ndarray, target, bit_depth: int | None = None, min_points: int | None = None,
                  method: str | None = None, explain: bool = False):
    """Detect any target: :func:`detect_dots` (``method``: one of METHODS), :func:`detect_chessboard`
    or :func:`detect_charuco`. ``explain``: return ``(Detection | None, reason)``."""
    method = method or default_method(target)
    if isinstance(target, DotGrid):
        return detect_dots(image, target, bit_depth, min_points, method, explain)
    if isinstance(target, Chessboard):
        return detect_chessboard(image, target, bit_depth, min_points, explain)
    return detect_charuco(image, target, bit_depth, min_points, explain)
