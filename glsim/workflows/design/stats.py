"""Summaries over the finite entries of an error map (NaN: a subset invalid or outside the ROI), and
the common points of several realisations' results."""
from __future__ import annotations

import math

import numpy as np

P95 = 95


def pct(a: np.ndarray, q: float = P95) -> float:
    a = a[np.isfinite(a)]
    return float(np.percentile(a, q)) if a.size else math.nan


def rms(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a ** 2))) if a.size else math.nan


def median(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else math.nan


def common_points(xs: list[np.ndarray], ys: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """The points (x, y; rounded to 1e-3 px) every realisation has, sorted, and each realisation's
    indices of them — its arrays taken with these line up across realisations."""
    keys = [set(zip(np.round(x, 3), np.round(y, 3))) for x, y in zip(xs, ys)]
    common = sorted(set.intersection(*keys))
    idx = []
    for x, y in zip(xs, ys):
        where = {xy: i for i, xy in enumerate(zip(np.round(x, 3), np.round(y, 3)))}
        idx.append(np.array([where[c] for c in common], np.int64))
    return np.array([c[0] for c in common]), np.array([c[1] for c in common]), idx
