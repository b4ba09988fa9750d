"""Reference-image interpolation: coefficient images and separable kernels.

This is the float64 numpy oracle of ``shaders/interp.glsl``: same kernels, same tap
order, same index clamping. Pixel coordinates (u, v): u = column, v = row, pixel
centres at integers, origin at the top-left pixel's centre.

Methods:
    ``"linear"``    bilinear, 2x2 taps
    ``"cubic"``     Keys cubic convolution (a = -0.5), 4x4 taps
    ``"bspline3"``  cubic B-spline interpolation, 4x4 taps on prefiltered coefficients
    ``"bspline5"``  quintic B-spline interpolation, 6x6 taps on prefiltered coefficients

Boundary: the image is extended by whole-sample symmetry (scipy's ``mode="mirror"``,
numpy's ``pad(mode="reflect")``). The coefficient image carries ``PAD`` px of that
extension on every side, so samples up to ``PAD - 3`` px outside the image are exact
for every method; farther out the tap indices are clamped to the padded array's edge
(the renderer masks samples outside the reference image anyway).
"""

import numpy as np
from scipy import ndimage

from glsim.errors import SceneError

PAD = 4  # px of mirror extension around the coefficient image; keep in sync with REF_PAD in shaders/interp.glsl
METHODS = ("linear", "cubic", "bspline3", "bspline5")

_SUPPORT = {"linear": 2, "cubic": 4, "bspline3": 4, "bspline5": 6}  # taps per axis
_FIRST = {"linear": 0, "cubic": -1, "bspline3": -1, "bspline5": -2}  # first tap offset from floor(x)
_SPLINE_ORDER = {"bspline3": 3, "bspline5": 5}


def _check_method(method):
    if method not in _SUPPORT:
        raise SceneError("interpolation", f"unknown method {method!r}", f"use one of {', '.join(METHODS)}")


def taps(method):
    """Texel reads per sample (2-D): 4, 16, 16 or 36."""
    _check_method(method)
    return _SUPPORT[method] ** 2


def prepare(image, method, dtype=np.float32):
    """Coefficient image of a greyscale (H, W) image, padded by ``PAD`` px on every side.

    For ``linear``/``cubic`` the coefficients are the grey levels; for the B-splines they
    are the ``scipy.ndimage.spline_filter(image, order, mode="mirror")`` coefficients. The
    padding is the mirror extension. Returns (H + 2 PAD, W + 2 PAD) in ``dtype`` (float32
    for the R32F texture; float64 for exact CPU comparisons).
    """
    _check_method(method)
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2 or min(img.shape) < 2:
        raise SceneError("reference image", f"expected a 2-D (H, W) image of at least 2x2 px, got shape {img.shape}",
                         "give a single-channel greyscale image")
    if method in _SPLINE_ORDER:
        # Prefilter unpadded: padding mirror coefficients by reflection is their exact mirror extension.
        img = ndimage.spline_filter(img, _SPLINE_ORDER[method], output=np.float64, mode="mirror")
    return np.pad(img, PAD, mode="reflect").astype(dtype)


def weights(t, method):
    """Per-axis kernel weights at fractional offsets ``t`` in [0, 1): a list of arrays, one per tap.

    Tap k multiplies the coefficient at ``floor(x) + first + k`` with first = 0 (linear),
    -1 (cubic, bspline3) or -2 (bspline5). Written operation for operation like the GLSL.
    """
    _check_method(method)
    t = np.asarray(t, dtype=np.float64)
    if method == "linear":
        return [1.0 - t, t]
    if method == "cubic":
        # Keys (1981) with a = -0.5.
        return [
            t * (-1.0 + t * (2.0 - t)) * 0.5,
            (2.0 + t * t * (-5.0 + 3.0 * t)) * 0.5,
            t * (1.0 + t * (4.0 - 3.0 * t)) * 0.5,
            t * t * (t - 1.0) * 0.5,
        ]
    if method == "bspline3":
        s = 1.0 - t
        return [
            s * s * s / 6.0,
            (4.0 + t * t * (-6.0 + 3.0 * t)) / 6.0,
            (1.0 + t * (3.0 + t * (3.0 - 3.0 * t))) / 6.0,
            t * t * t / 6.0,
        ]
    s = 1.0 - t
    s2 = s * s
    t2 = t * t
    return [
        s2 * s2 * s / 120.0,
        (26.0 + t * (-50.0 + t * (20.0 + t * (20.0 + t * (-20.0 + 5.0 * t))))) / 120.0,
        (66.0 + t2 * (-60.0 + t2 * (30.0 - 10.0 * t))) / 120.0,
        (26.0 + t * (50.0 + t * (20.0 + t * (-20.0 + t * (-20.0 + 10.0 * t))))) / 120.0,
        (1.0 + t * (5.0 + t * (10.0 + t * (10.0 + t * (5.0 - 5.0 * t))))) / 120.0,
        t2 * t2 * t / 120.0,
    ]


def weight_derivatives(t, method):
    """d/dt of :func:`weights` at fractional offsets ``t``: one array per tap (they sum to 0).
    Linear's are the slopes of its pieces (the kernel has corners at the knots)."""
    _check_method(method)
    t = np.asarray(t, dtype=np.float64)
    if method == "linear":
        return [np.full(t.shape, -1.0), np.ones(t.shape)]
    if method == "cubic":
        return [(-1.0 + t * (4.0 - 3.0 * t)) * 0.5, t * (-10.0 + 9.0 * t) * 0.5,
                (1.0 + t * (8.0 - 9.0 * t)) * 0.5, t * (3.0 * t - 2.0) * 0.5]
    s = 1.0 - t
    if method == "bspline3":
        return [-0.5 * s * s, t * (-2.0 + 1.5 * t), 0.5 + t * (1.0 - 1.5 * t), 0.5 * t * t]
    return [-s * s * s * s / 24.0,
            (-50.0 + t * (40.0 + t * (60.0 + t * (-80.0 + 25.0 * t)))) / 120.0,
            t * (-120.0 + t * t * (120.0 - 50.0 * t)) / 120.0,
            (50.0 + t * (40.0 + t * (-60.0 + t * (-80.0 + 50.0 * t)))) / 120.0,
            (5.0 + t * (20.0 + t * (30.0 + t * (20.0 - 25.0 * t)))) / 120.0,
            t * t * t * t / 24.0]


def _taps(c, uv, method, wu, wv):
    """Σ_j wv[j] Σ_i wu[i] c[row j, column i] over the taps of ``uv`` (the clamping of :func:`sample`)."""
    n = _SUPPORT[method]
    f = np.floor(uv)
    rows, cols = c.shape
    # Clamp before the int cast; a first tap at -n or beyond reads only edge texels anyway.
    base = np.clip(np.nan_to_num(f) + (PAD + _FIRST[method]), -n, [cols, rows]).astype(np.intp)
    flat = c.ravel()
    acc = np.zeros(uv.shape[:-1])
    for j in range(n):
        row_start = np.clip(base[..., 1] + j, 0, rows - 1) * cols
        s = np.zeros(uv.shape[:-1])
        for i in range(n):
            s += wu[i] * flat[row_start + np.clip(base[..., 0] + i, 0, cols - 1)]
        acc += wv[j] * s
    return acc


def _checked(uv):
    uv = np.asarray(uv, dtype=np.float64)
    if uv.shape[-1:] != (2,):
        raise ValueError(f"uv must have shape (..., 2), got {uv.shape}")
    return uv


def sample(coeffs, uv, method):
    """Interpolated grey levels at pixel coordinates ``uv`` (..., 2) = (u, v) in unpadded image px.

    ``coeffs`` is ``prepare(image, method)``. Returns float64 of shape ``uv.shape[:-1]``;
    NaN coordinates give NaN.
    """
    _check_method(method)
    uv = _checked(uv)
    f = np.floor(uv)
    return _taps(np.asarray(coeffs), uv, method, weights(uv[..., 0] - f[..., 0], method),
                 weights(uv[..., 1] - f[..., 1], method))


def gradient(coeffs, uv, method):
    """The interpolant's analytic gradient (∂I/∂u, ∂I/∂v) (..., 2), grey levels per px, at ``uv``
    (..., 2): :func:`sample`'s sum with one axis' weights replaced by :func:`weight_derivatives`."""
    _check_method(method)
    uv = _checked(uv)
    t = uv - np.floor(uv)
    c = np.asarray(coeffs)
    wu, wv = weights(t[..., 0], method), weights(t[..., 1], method)
    du, dv = weight_derivatives(t[..., 0], method), weight_derivatives(t[..., 1], method)
    return np.stack([_taps(c, uv, method, du, wv), _taps(c, uv, method, wu, dv)], axis=-1)
