"""Quick mode: the Cramér–Rao bound of subset DIC from glsim's own noise-free image.

A subset DIC with shape function W(x; p) minimises Σ_subset [I_def(W(x; p)) − I_ref(x)]². About
the solution, the residual's change with the parameters is J = ∇I(x)·∂W/∂p (one row per subset
pixel), and each residual carries the noise of both images: variance σ_ref² + σ_def² per pixel
(the reference image of a test is a noisy image too). With Gaussian noise the parameters' covariance
is then (Jᵀ Σ⁻¹ J)⁻¹, Σ = diag(σ_ref² + σ_def²): for a constant σ, 2σ²(JᵀJ)⁻¹ — the Cramér–Rao
bound of any unbiased estimator that uses these pixels and this shape function, to first order
(the noise of the gradient itself, interpolation and the ZNSSD's normalisation are neglected).

For the zero-order (rigid) shape function J = [I_x, I_y] and, where Σ I_x I_y is small against
Σ I_x² and Σ I_y², σ_u = √2·σ/√(Σ I_x²): Pan et al.'s SSSIG prediction (Pan, Xie, Wang, Qian & Wang,
Opt. Express 2008; the √2 is the noise of both images).

Columns of J by shape function (dx, dy = x − x0, y − y0, the pixel's offset from the subset centre):

- rigid: u, v → I_x, I_y
- affine: u, u_x, u_y, v, v_x, v_y → I_x·(1, dx, dy), I_y·(1, dx, dy)
- quad: affine and u_xx, u_xy, u_yy, v_xx, v_xy, v_yy → I_x·(dx²/2, dx·dy, dy²/2), I_y·(…)

∇I is the derivative of the image's cubic B-spline interpolant at the pixel centres (the
interpolant of a B-spline DIC such as pyvale's; :func:`spline_gradient`).
σ per pixel is the scene's noise model at the noise-free grey (:func:`glsim.effects.noise.noise_sigma`)
plus the quantisation of the camera's bit depth (a uniform error of one level: variance 1/12 level²).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from glsim.effects import noise as noisemod

# the powers (a, b) of dx^a·dy^b / (a!·b!) per shape function, in the order of the parameters
TERMS = {"rigid": ((0, 0),),
         "affine": ((0, 0), (1, 0), (0, 1)),
         "quad": ((0, 0), (1, 0), (0, 1), (2, 0), (1, 1), (0, 2))}
MAX_CENTRES_PER_BATCH = 512


def spline_gradient(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(I_x, I_y) of ``image``'s cubic B-spline interpolant at the pixel centres, grey per px:
    along the derivative's axis (c[i+1] − c[i−1])/2 of the coefficients c (β₃'(±1) = ∓1/2), along
    the other the B-spline's own weights (1, 4, 1)/6 (β₃(0) = 2/3, β₃(±1) = 1/6)."""
    c = ndimage.spline_filter(np.asarray(image, np.float64), order=3, mode="mirror")
    d = ndimage.correlate1d(c, [-0.5, 0.0, 0.5], axis=1, mode="mirror")
    gx = ndimage.correlate1d(d, [1 / 6, 4 / 6, 1 / 6], axis=0, mode="mirror")
    d = ndimage.correlate1d(c, [-0.5, 0.0, 0.5], axis=0, mode="mirror")
    gy = ndimage.correlate1d(d, [1 / 6, 4 / 6, 1 / 6], axis=1, mode="mirror")
    return gx, gy


def pixel_variance(image: np.ndarray, noise, bit_depth: int, table=None, quantisation: bool = True) -> np.ndarray:
    """Per-pixel variance (full scale²) of one camera image: the noise model's at the noise-free
    grey ``image`` (0 without noise) plus the quantisation's 1/12 level²."""
    var = np.zeros(image.shape)
    if noise is not None:
        var = np.broadcast_to(noisemod.noise_sigma(np.asarray(image, np.float64), noise, bit_depth, table),
                              image.shape) ** 2
    if quantisation:
        var = var + (1.0 / (2 ** bit_depth - 1)) ** 2 / 12
    return np.asarray(var, np.float64)


def grid_centres(roi: np.ndarray, subset_size: int, step: int) -> np.ndarray:
    """(n, 2) integer (x, y) subset centres on a ``step`` grid whose whole subset lies in ``roi``."""
    inside = ndimage.binary_erosion(roi, np.ones((subset_size, subset_size), bool), border_value=0)
    rows, cols = np.nonzero(inside)
    if not len(rows):
        return np.zeros((0, 2), np.int64)
    y0, x0 = rows.min(), cols.min()
    keep = ((rows - y0) % step == 0) & ((cols - x0) % step == 0)
    return np.stack([cols[keep], rows[keep]], axis=1).astype(np.int64)


def _design_columns(gx: np.ndarray, gy: np.ndarray, offsets: np.ndarray, shape: str) -> np.ndarray:
    """(n, m, P) J of n subsets of m pixels: gradients (n, m), offsets (m, 2) dx, dy."""
    dx, dy = offsets[:, 0], offsets[:, 1]
    factorial = (1.0, 1.0, 2.0)
    basis = [dx ** a * dy ** b / (factorial[a] * factorial[b]) for a, b in TERMS[shape]]
    return np.concatenate([np.stack([g * t for t in basis], axis=-1) for g in (gx, gy)], axis=-1)


def crb(image: np.ndarray, variance: np.ndarray, centres: np.ndarray, subset_size: int, shape: str,
        both_noisy: bool = True) -> dict[str, np.ndarray]:
    """Per subset centre (n, 2 integers x, y): the Cramér–Rao σ of u and v (px) of a subset DIC with
    ``shape`` on ``image`` (noise-free, full scale) with per-pixel ``variance`` (full scale²); with
    ``both_noisy`` the residual's variance is twice the image's (reference and deformed images alike).
    Also ``sssig_x``, ``sssig_y`` (Σ I_x², Σ I_y² over the subset) and ``ok`` (the Fisher matrix
    invertible: a subset on a flat grey gives ∞)."""
    gx, gy = spline_gradient(image)
    h = subset_size // 2
    dy, dx = np.mgrid[-h:h + 1, -h:h + 1]
    offsets = np.stack([dx.ravel(), dy.ravel()], axis=1).astype(np.float64)
    n = len(centres)
    su, sv = np.full(n, np.inf), np.full(n, np.inf)
    sx, sy = np.zeros(n), np.zeros(n)
    weight = 1.0 / (variance * (2.0 if both_noisy else 1.0))
    P = 2 * len(TERMS[shape])
    for a in range(0, n, MAX_CENTRES_PER_BATCH):
        c = centres[a:a + MAX_CENTRES_PER_BATCH]
        ys = c[:, 1, None] + dy.ravel()[None, :]
        xs = c[:, 0, None] + dx.ravel()[None, :]
        Gx, Gy, w = gx[ys, xs], gy[ys, xs], weight[ys, xs]
        J = _design_columns(Gx, Gy, offsets, shape)
        F = np.einsum("nmp,nm,nmq->npq", J, w, J)
        sx[a:a + len(c)] = np.sum(Gx ** 2, axis=1)
        sy[a:a + len(c)] = np.sum(Gy ** 2, axis=1)
        good = np.linalg.cond(F) < 1e12
        cov = np.full_like(F, np.nan)
        cov[good] = np.linalg.inv(F[good])
        iu, iv = 0, P // 2
        su[a:a + len(c)] = np.where(good, np.sqrt(np.abs(cov[:, iu, iu])), np.inf)
        sv[a:a + len(c)] = np.where(good, np.sqrt(np.abs(cov[:, iv, iv])), np.inf)
    return {"sigma_u": su, "sigma_v": sv, "sssig_x": sx, "sssig_y": sy, "ok": np.isfinite(su) & np.isfinite(sv)}


def sssig_sigma(sssig: np.ndarray, sigma: float) -> np.ndarray:
    """Pan et al.'s prediction √2·σ/√SSSIG (noise σ in both images, full scale; SSSIG grey²/px²)."""
    with np.errstate(divide="ignore"):
        return np.sqrt(2.0) * sigma / np.sqrt(sssig)
