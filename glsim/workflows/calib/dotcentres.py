"""Sub-pixel dot centres of a found grid (:func:`refine`): the model fit of
:mod:`~glsim.workflows.calib.dotfit` (``method="fit"``, the default), and other estimators,
kept for the comparison (``METHODS``): ``centroid`` Σ(I − b)·p / Σ(I − b) over ±0.45 local grid
spacings (b: the window's outer ring; iterated, re-centred); ``centroid-dot`` the same over the
dot's ellipse grown by 3 px; ``edge-ellipse`` an ellipse fitted to sub-pixel edge points
(half-contrast crossings along rays); ``blob`` OpenCV's blob centres.
"""
from __future__ import annotations

import numpy as np

from glsim.errors import SceneError
from glsim.workflows.calib.dotfit import (EDGE_BAND, WINDOW, Ellipses, band_pixels, fit_ellipses, initial_ellipses,
                                          window_pixels)
from glsim.workflows.calib.dotgrid import grid_vectors
from glsim.workflows.calib.targets import DotGrid

ITERATIONS = 4         # centroid passes, each re-centring the window
METHODS = ("fit", "centroid", "centroid-dot", "edge-ellipse", "blob")


def centroid(image: np.ndarray, centre, e_col, e_row, white: bool, ring: float,
             window: float = WINDOW) -> tuple[np.ndarray, float] | None:
    """One grey-level centroid pass (see the module text): ``(centre, mass)`` with mass =
    Σ(I − b) in grey × px², or None if the window leaves the image.

    ``ring``: inner edge of the background ring, in grid spacings (outside every dot).
    """
    win = window_pixels(image, centre, e_col, e_row, window)
    if win is None:
        return None
    p, I, m = win
    bg = np.median(I[m >= ring])
    w = I - bg if white else bg - I
    mass = w.sum()
    if not mass > 0:
        return None
    return (w @ p) / mass, float(mass)


def refine_centroid(image: np.ndarray, points: np.ndarray, target: DotGrid, window: float = WINDOW, vectors=None):
    """Grey-level centroids of all dots in windows of ±``window`` grid spacings: ``(points,
    area)`` where area (N,) is each dot's mass over its local grid cell area (≈ (dot area /
    pitch²)·contrast); NaN where lost. (The estimator before the model fit; kept for the
    comparison in examples/calib_detection.py.)"""
    e_col, e_row = vectors if vectors is not None else grid_vectors(points, target.rows, target.cols)
    ring = (float(np.max(target.diameters())) / 2 / target.pitch + window) / 2   # between dots and edge
    out = np.full_like(points, np.nan)
    area = np.full(len(points), np.nan)
    for k, c in enumerate(points):
        if np.isnan(c[0]):
            continue
        cell = abs(e_col[k, 0] * e_row[k, 1] - e_col[k, 1] * e_row[k, 0])
        for _ in range(ITERATIONS):
            r = centroid(image, c, e_col[k], e_row[k], target.white_dots, ring, window)
            if r is None:
                break
            c, mass = r
        else:
            out[k], area[k] = c, mass / cell
    return out, area


def refine_fit(image: np.ndarray, points: np.ndarray, target: DotGrid, band: float = EDGE_BAND, vectors=None):
    """Model-fitted centres of all dots (see :func:`fit_ellipses`): ``(points, area, ellipses)``
    with area (N,) each dot's ellipse area over its local grid cell area; NaN where lost.
    The band is ``band`` px, less where the gap to the next dots is narrower (0.45 × the gap
    between this dot's edge and a full-size neighbour's). ``vectors``: the local grid vectors
    (e_col, e_row) (N, 2) each, if not those of a complete grid (:func:`grid_vectors`)."""
    e_col, e_row = vectors if vectors is not None else grid_vectors(points, target.rows, target.cols)
    start, cell = _start(image, points, target, vectors)
    with np.errstate(invalid="ignore"):
        radius = np.sqrt(np.linalg.eigvalsh(np.linalg.inv(np.where(np.isfinite(start.M), start.M, np.eye(2))))[:, 1])
        spacing = np.minimum(np.linalg.norm(e_col, axis=1), np.linalg.norm(e_row, axis=1))
        gap = spacing - radius - np.nanmedian(np.where(np.isfinite(start.centres[:, 0]), radius, np.nan))
    e = fit_ellipses(image, start, target.white_dots, np.minimum(band, 0.45 * gap))
    return e.centres, e.areas / cell, e


def _start(image, points, target, vectors=None):
    e_col, e_row = vectors if vectors is not None else grid_vectors(points, target.rows, target.cols)
    ring = (float(np.max(target.diameters())) / 2 / target.pitch + WINDOW) / 2
    cell = np.abs(e_col[:, 0] * e_row[:, 1] - e_col[:, 1] * e_row[:, 0])
    return initial_ellipses(image, points, e_col, e_row, target.white_dots, ring), cell


def refine_dot_centroid(image: np.ndarray, points: np.ndarray, target: DotGrid, margin: float = 3.0, vectors=None):
    """Grey-level centroids in windows sized from each dot: the pixels within ``margin`` px
    outside its (initial) ellipse, background the median of the next 3 px; 3 passes
    re-centring the window. ``(points, area)`` as :func:`refine_centroid`."""
    start, cell = _start(image, points, target, vectors)
    out = np.full_like(points, np.nan)
    area = np.full(len(points), np.nan)
    sign = 1.0 if target.white_dots else -1.0
    for k in np.flatnonzero(np.isfinite(start.centres[:, 0])):
        e = start
        c = e.centres[k]
        for _ in range(3):
            bp = band_pixels(image, Ellipses(c[None], e.M[k][None], *(x[k:k + 1] for x in (e.background, e.contrast,
                                                                                             e.edge, e.rms))),
                             0, margin + 3.0, inner=False)
            if bp is None:
                c = None
                break
            p, I, d = bp
            bg = np.median(I[d > margin])
            w = sign * (I - bg) * (d <= margin)
            if not w.sum() > 0:
                c = None
                break
            c = (w @ p) / w.sum()
            mass = w.sum()
        if c is not None:
            out[k], area[k] = c, mass / abs(e.contrast[k]) / cell[k]
    return out, area


def refine_edge_ellipse(image: np.ndarray, points: np.ndarray, target: DotGrid, reach: float = 3.0, vectors=None):
    """Ellipses fitted (cv2.fitEllipseDirect) to sub-pixel edge points: along one ray per px of
    each dot's (initial) outline, where the bilinearly interpolated grey crosses halfway
    between the background and the dot's level. ``(points, area)`` as :func:`refine_centroid`."""
    import cv2
    from scipy.ndimage import map_coordinates
    start, cell = _start(image, points, target, vectors)
    out = np.full_like(points, np.nan)
    area = np.full(len(points), np.nan)
    H, W = image.shape
    steps = np.arange(-reach, reach + 1e-9, 0.25)
    for k in np.flatnonzero(np.isfinite(start.centres[:, 0])):
        c, M = start.centres[k], start.M[k]
        L = np.linalg.cholesky(np.linalg.inv(M))            # outline: c + L·(cos, sin)
        n = max(int(np.ceil(2 * np.pi * np.sqrt(np.abs(np.linalg.det(L))))), 16)
        ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
        edge = c + np.stack([np.cos(ang), np.sin(ang)], 1) @ L.T
        normal = (edge - c) @ M
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        samples = edge[:, None, :] + steps[None, :, None] * normal[:, None, :]
        if samples[..., 0].min() < 0 or samples[..., 1].min() < 0 or samples[..., 0].max() > W - 1 or \
                samples[..., 1].max() > H - 1:
            continue
        g = map_coordinates(image, [samples[..., 1].ravel(), samples[..., 0].ravel()], order=1).reshape(samples.shape[:2])
        level = start.background[k] + start.contrast[k] / 2
        above = (g - level) * np.sign(start.contrast[k]) > 0          # inside the dot
        pts = []
        for i in range(n):
            j = np.flatnonzero(above[i, :-1] & ~above[i, 1:])          # last inside → first outside
            if len(j) != 1:
                continue
            j = j[0]
            f = (g[i, j] - level) / (g[i, j] - g[i, j + 1])
            pts.append(samples[i, j] + f * (samples[i, j + 1] - samples[i, j]))
        if len(pts) < 8:
            continue
        q = (np.asarray(pts) - c).astype(np.float32).reshape(-1, 1, 2)     # float32: relative to c
        (ex, ey), (a2, b2), _ = cv2.fitEllipseDirect(q)
        out[k], area[k] = c + (ex, ey), np.pi * a2 * b2 / 4 / cell[k]
    return out, area


def refine(image: np.ndarray, points: np.ndarray, target: DotGrid, method: str = "fit", vectors=None):
    """Sub-pixel centres of all dots by ``method`` (one of METHODS): ``(points, area)``; rows of
    ``points`` that are NaN (dots not found) stay NaN. ``vectors``: see :func:`refine_fit`."""
    if method == "fit":
        return refine_fit(image, points, target, vectors=vectors)[:2]
    if method == "centroid":
        return refine_centroid(image, points, target, vectors=vectors)
    if method == "centroid-dot":
        return refine_dot_centroid(image, points, target, vectors=vectors)
    if method == "edge-ellipse":
        return refine_edge_ellipse(image, points, target, vectors=vectors)
    if method == "blob":
        start, cell = _start(image, points, target, vectors)
        return points.copy(), start.areas / cell
    raise SceneError("method", f"{method!r} is not one of {METHODS}", "choose a dot-centre estimator")
