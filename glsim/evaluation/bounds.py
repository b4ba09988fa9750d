"""Bounds of the GL path's error against the CPU oracle, derived from the arithmetic of each
mode (issue 25), for ``glsim check`` and the GL tests: the same bounds on llvmpipe and on a GPU.
The camera passes' (vignetting, PSF, fixed pattern): :func:`camera_passes`.

- **float64 (exact, q4, and their truth)**: unit roundoff 2^-53 = 1.1e-16 on coordinates below
  1e4 (px or mm) is 1.1e-12; the closed-form roots, two Newton polishes and the projections
  multiply it by their conditioning, below 1e3 for any element the tie rule lets through
  (folded and grazing ones included); ``FLOAT64`` = 1e-9 keeps a factor of ten on top.
- **float32 (fast)**: each vertex is projected in float32 — the camera transform R·x + t' of a
  node relative to the mesh's origin (terms up to the camera's distance D ≈ Z: 3 roundings per
  component, each ≤ 2^-24 of D), the division x/z, the distortion polynomial and the pixel
  mapping (about 6 more roundings relative to |xn| ≤ 1) — so a vertex lies within
  fx·12·2^-24 px of the oracle's; the float32 interpolation between the vertices (edge
  functions over differences < 2^8 px) adds under 1e-5 px. What moves a vertex by δ px moves
  an interpolated quantity by δ times its derivative per image pixel (:func:`per_pixel`): a
  reference point by δ·|∂ref/∂uv| (57× at a plate seen at 89°), a material point by δ·|∂X/∂uv|.
"""
from __future__ import annotations

import numpy as np

FLOAT64 = 1e-9                # px or mm: exact and q4 (reference points, truth X, ξ η-derived maps)
FLOAT32_ROUNDOFF = 2.0 ** -24


def fast_px(fx: float) -> float:
    """Bound (px) of a fast-mode vertex's image position against the oracle's, camera focal
    length ``fx`` px (module docstring)."""
    return fx * 12 * FLOAT32_ROUNDOFF + 1e-5


def per_pixel(field: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """|∂field/∂(u, v)| per pixel (H, W): the largest norm of the differences to its four
    neighbours that are also in ``mask``; a pixel without such a neighbour takes the largest
    value of the image. ``field`` (H, W, k)."""
    out = np.full(mask.shape, -1.0)
    for axis in (0, 1):
        n = mask.shape[axis]
        d = np.linalg.norm(np.diff(field, axis=axis), axis=-1)
        ok = np.take(mask, range(n - 1), axis) & np.take(mask, range(1, n), axis)
        d = np.where(ok, d, -1.0)
        for pad in ((1, 0), (0, 1)):   # the difference to the previous pixel, then to the next
            out = np.maximum(out, np.pad(d, [pad if a == axis else (0, 0) for a in (0, 1)], constant_values=-1.0))
    seen = out >= 0
    return np.where(seen, out, out[seen].max() if seen.any() else 0.0)


def fast_bound(fx: float, field: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per pixel: the bound of a fast-mode quantity interpolated over the vertices (a reference
    point in px or a material point in mm; ``field`` the oracle's map of it, (H, W, k)) against
    the oracle's."""
    return fast_px(fx) * per_pixel(field, mask) + FLOAT64


def camera_passes(fx, base: np.ndarray) -> float:
    """The largest |GL − oracle| (full scale) the float32 arithmetic of the camera passes allows
    on the same input image ``base`` with :class:`~glsim.effects.Effects` ``fx`` (M = max |value|
    along the way; u = 2^-24; γ_n ≈ n·u for a sum of n products, Higham §3.1):
    vignette: the gain's rounding, the product's, the oracle's final rounding: 3u·M;
    PSF: per pass the kernel's weights (u), the n products and sums (n·u) over Σ|w|·M = M, and
    the oracle's final rounding: separable (n = 2R + 1, two passes) 2(n + 1)u·M + u·M; 2-D
    (n = (2R + 1)²) (n + 1)u·M + u·M;
    fixed pattern: GLSL's cos is only good to 2^-11 absolute (GLSL 4.50 §8.1), sqrt and our log to
    a few ulps: |Δz| ≤ 5.77·2^-11 + 5.77·8u (|z| ≤ 5.77, the 24-bit bound); times the gain σ·M
    and the offset σ, plus 4u·M for the roundings."""
    u = FLOAT32_ROUNDOFF
    M = float(np.abs(base).max()) * max(float(fx.vignette.max()) if fx.vignette is not None else 1.0, 1.0)
    if fx.fixed_pattern:    # |z| ≤ 5.77
        M = M * (1 + fx.sensor.prnu / 100 * 5.77) + fx.sensor.dsnu / ((1 << fx.bit_depth) - 1) * 5.77
    bound = 0.0
    if fx.vignette is not None:
        bound += 3 * u * M
    if fx.psf is not None:
        n = 2 * fx.psf.radius + 1
        bound += (2 * (n + 1) * u * M if fx.psf.taps is not None else (n * n + 1) * u * M) + u * M
    if fx.fixed_pattern:
        dz = 5.77 * 2.0 ** -11 + 5.77 * 8 * u
        bound += fx.sensor.prnu / 100 * M * dz + fx.sensor.dsnu / ((1 << fx.bit_depth) - 1) * dz + 4 * u * M
    return bound
