"""Stage "psf": the lens point-spread function, numpy float64 (the oracle; shaders/psf.frag is
the GL pass).

The kernel's weight at offset (i, j) px is the PSF integrated over that pixel cell
[i − ½, i + ½] × [j − ½, j + ½] (the share of a point source at a pixel centre that falls on
each pixel), normalised to sum 1 over the kernel's square. It is convolved with the
pixel-integrated irradiance, clamp to edge (pixels beyond the image repeat its border).

``gaussian``  cells integrated in closed form: t(i) = Φ((i + ½)/σ) − Φ((i − ½)/σ), |i| ≤ ⌈4σ⌉
              (the tail beyond holds 2·Φ(−4) = 6e-5 of the energy); separable: two 1-D passes.
``airy``      I(r) = (2·J1(x)/x)², x = π·r/(λ·N) (r in the image plane): first zero at
              r = 1.2197·λ·N. Cells integrated with 8 × 8 Gauss–Legendre points; the kernel
              reaches the radius holding 99 % of the energy (1 − J0(x)² − J1(x)² = 0.99,
              x = 63.66, r ≈ 16.6 first-zero radii).
``image``     a measured PSF, sampled in px: odd sides, centred (its centroid within ½ px of
              the middle pixel), no negative values; normalised to sum 1.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.errors import SceneError

GAUSS_RADIUS_SIGMAS = 4.0        # the Gaussian kernel's half-width in σ
AIRY_ENERGY = 0.99               # the Airy kernel holds this share of the disk's energy
AIRY_NODES = 8                   # Gauss–Legendre points per cell side
MAX_RADIUS = 64                  # px: larger kernels are refused (129 × 129 taps per pixel)


@dataclass(frozen=True, eq=False)
class Kernel:
    """``kernel`` (2R + 1, 2R + 1) float64, sum 1, centred; ``taps`` its 1-D factor when it is
    separable (the Gaussian: kernel = outer(taps, taps)), else None."""
    kernel: np.ndarray
    taps: np.ndarray | None = None

    @property
    def radius(self) -> int:
        return self.kernel.shape[0] // 2


def gaussian_taps(sigma: float) -> np.ndarray:
    """The Gaussian's cell integrals over |i| ≤ ⌈4σ⌉, normalised (float64)."""
    from scipy.special import ndtr

    R = _radius(math.ceil(GAUSS_RADIUS_SIGMAS * sigma), "psf.sigma", "give σ ≤ 16 px")
    i = np.arange(-R, R + 1, dtype=np.float64)
    t = ndtr((i + 0.5) / sigma) - ndtr((i - 0.5) / sigma)
    return t / t.sum()


def airy(r_px, wavelength_nm: float, f_number: float, pixel_pitch: float) -> np.ndarray:
    """The Airy pattern (2·J1(x)/x)² at radii ``r_px`` (px), peak 1."""
    from scipy.special import j1

    x = math.pi * np.asarray(r_px, np.float64) * pixel_pitch / (wavelength_nm * 1e-6 * f_number)
    safe = np.where(x == 0, 1.0, x)
    return np.where(x == 0, 1.0, (2.0 * j1(safe) / safe) ** 2)


def airy_radius(wavelength_nm: float, f_number: float, pixel_pitch: float) -> int:
    """The Airy kernel's half-width (px): the radius holding AIRY_ENERGY of the energy."""
    from scipy.optimize import brentq
    from scipy.special import j0, j1

    # the encircled energy 1 − J0² − J1² rises monotonically; its 0.99 lies beyond x = 50
    x = brentq(lambda x: 1.0 - j0(x) ** 2 - j1(x) ** 2 - AIRY_ENERGY, 50.0, 80.0)
    r = x / math.pi * wavelength_nm * 1e-6 * f_number / pixel_pitch
    return _radius(math.ceil(r), "psf.f_number", "give a smaller f-number or wavelength, or a larger pixel pitch")


def airy_kernel(wavelength_nm: float, f_number: float, pixel_pitch: float) -> np.ndarray:
    """The Airy disk's cell integrals over the square of :func:`airy_radius`, normalised."""
    R = airy_radius(wavelength_nm, f_number, pixel_pitch)
    g, w = np.polynomial.legendre.leggauss(AIRY_NODES)
    offs = np.arange(-R, R + 1, dtype=np.float64)
    pts = (offs[:, None] + 0.5 * g[None, :]).ravel()          # every cell's nodes along an axis
    wts = np.tile(0.5 * w, offs.size)
    n = offs.size
    val = airy(np.hypot(pts[:, None], pts[None, :]), wavelength_nm, f_number, pixel_pitch)
    cells = (val * wts[:, None] * wts[None, :]).reshape(n, AIRY_NODES, n, AIRY_NODES).sum(axis=(1, 3))
    return cells / cells.sum()


def image_kernel(path: Path) -> np.ndarray:
    """A measured PSF file as a kernel: odd sides, centred, ≥ 0, normalised (SceneError otherwise)."""
    from glsim.io.images import check_image_header, read_image
    from glsim.limits import require_file

    side = 2 * MAX_RADIUS + 1
    require_file(path, "psf.image", "give a greyscale TIFF or PNG file (path relative to the scene file)")
    check_image_header(path, "psf.image", "PSF image", f"crop the PSF to at most {side} px a side", side)
    try:
        a = np.asarray(read_image(path), np.float64)
    except (OSError, ValueError) as exc:
        raise SceneError("psf.image", f"cannot read {path} ({exc})", "give a greyscale TIFF or PNG") from None
    if a.ndim != 2 or a.shape[0] % 2 == 0 or a.shape[1] % 2 == 0:
        raise SceneError("psf.image", f"{path.name} is {' × '.join(map(str, a.shape[::-1]))} px",
                         "give a greyscale PSF with odd sides (its centre on the middle pixel), e.g. 15 × 15")
    if not np.all(np.isfinite(a)) or a.min() < 0 or a.sum() <= 0:
        raise SceneError("psf.image", f"{path.name} holds negative, non-finite or only zero values",
                         "give the PSF's intensities (≥ 0, not all 0; background subtracted)")
    H, W = a.shape
    _radius(max(H, W) // 2, "psf.image", f"crop the PSF to at most {2 * MAX_RADIUS + 1} px a side")
    a = a / a.sum()
    cy, cx = (a.sum(axis=1) @ np.arange(H)) - H // 2, (a.sum(axis=0) @ np.arange(W)) - W // 2
    if max(abs(cx), abs(cy)) > 0.5:
        raise SceneError("psf.image", f"{path.name}'s centroid lies ({cx:+.2f}, {cy:+.2f}) px from its middle pixel",
                         "centre the PSF on the middle pixel (shift it by whole pixels) before giving it")
    R = max(H, W) // 2
    out = np.zeros((2 * R + 1, 2 * R + 1))
    out[R - H // 2:R + H // 2 + 1, R - W // 2:R + W // 2 + 1] = a
    return out


def _radius(R: int, key: str, fix: str) -> int:
    if R > MAX_RADIUS:
        raise SceneError(key, f"makes a PSF kernel of {2 * R + 1} px a side, over glsim's {2 * MAX_RADIUS + 1}", fix)
    return max(int(R), 1)


@functools.lru_cache(maxsize=8)
def _kernel_cached(kind: str, sigma: float, wavelength_nm: float, f_number: float, pixel_pitch: float,
                   path: str) -> Kernel:
    if kind == "gaussian":
        t = gaussian_taps(sigma)
        k = Kernel(np.outer(t, t), t)
    elif kind == "airy":
        k = Kernel(airy_kernel(wavelength_nm, f_number, pixel_pitch))
    else:
        k = Kernel(image_kernel(Path(path)))
    for a in (k.kernel, k.taps):
        if a is not None:
            a.flags.writeable = False
    return k


def make_kernel(psf, base: Path | None = None) -> Kernel:
    """The :class:`Kernel` of the scene's [psf] table (``base`` resolves its image path)."""
    path = str(Path(base or ".") / psf.image) if psf.image else ""
    return _kernel_cached(psf.kind, psf.sigma, psf.wavelength_nm, psf.f_number, psf.pixel_pitch, path)


def matrix(k: Kernel, size: tuple[int, int]):
    """:func:`apply` as a scipy.sparse CSR matrix acting on row-major images of ``size`` (W, H):
    ``(matrix(k, (W, H)) @ I.ravel()).reshape(H, W)`` is ``apply(I, k)`` to rounding (the image
    Jacobian through the PSF). (2R + 1)² entries per row, fewer at the border, where clamped
    taps add up."""
    from scipy import sparse

    W, H, R = *size, k.radius
    y, x = np.divmod(np.arange(W * H), W)
    rows, cols, vals = [], [], []
    for (a, b), w in np.ndenumerate(k.kernel):   # a convolution: tap (a, b) reads pixel p − (a, b) + R
        if w:
            rows.append(y * W + x)
            cols.append(np.clip(y - a + R, 0, H - 1) * W + np.clip(x - b + R, 0, W - 1))
            vals.append(np.full(W * H, w))
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(W * H,) * 2)


def apply(image: np.ndarray, k: Kernel) -> np.ndarray:
    """The image (H, W) convolved with the kernel in float64, clamp to edge."""
    from scipy import ndimage

    return ndimage.convolve(np.asarray(image, np.float64), k.kernel, mode="nearest")


def through_kernel(J, k: Kernel, size: tuple[int, int]):
    """The derivative of the lens PSF: an image Jacobian ``J`` (W·H × n, sparse) of the image of
    ``size`` (W, H) before it → after the convolution (clamp to edge, :func:`matrix`). SceneError
    naming [psf] where the product would need more memory than this process may use."""
    from glsim.limits import memory_budget

    W, H = size
    taps = int(np.count_nonzero(k.kernel))
    need, budget = 24 * taps * (W * H + J.nnz), memory_budget()   # (row, column, value) per entry
    if need > budget:
        raise SceneError("psf", f"the image Jacobian through its {2 * k.radius + 1} px kernel needs about "
                         f"{need / 2**30:.3g} GiB, more than the {budget / 2**30:.3g} GiB this process may use",
                         "render a smaller camera (a region of interest), give a narrower PSF, or render "
                         "without jacobian")
    return matrix(k, (W, H)) @ J
