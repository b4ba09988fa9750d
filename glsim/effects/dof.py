"""Depth of field (reference paper §2.2.2, eqs. 14–19) and the depth-dependent blur, numpy float64.

The GLSL twin is ``shaders/dof.glsl`` (``coc_px``, ``blur_sigma``, ``blur_radius``, same names
and formulas) with ``shaders/blur.frag`` (the passes that ``blur_separable`` and ``blur_disk``
mirror). Lengths in millimetres, blur sizes in pixels.

Optics parameters are read by attribute name from any object (a frozen dataclass, a
``SimpleNamespace``) or from a mapping: ``focal_length`` f (mm), ``f_number`` N,
``focus_distance`` D (mm, along the optical axis: a surface point's distance is its
camera-frame depth Z), ``pixel_pitch`` (mm), ``coc_px`` (acceptable circle of confusion in
pixels, default 1: the paper takes the pixel size) and ``kernel`` ("gaussian", default, or
"disk").

Choices made here (the paper leaves them open):

- **In focus** means CoC ≤ the acceptable circle of confusion (the paper's definition: "every
  point in the DOF will have a blur spot smaller than the acceptable circle of confusion");
  such pixels get σ = 0 and are copied unchanged. This band is evaluated with eq. 19 itself, so
  it differs slightly from eqs. 14–15, which are the usual D ≫ f approximations (f = 30 mm,
  N = 8, c = 4.4 µm, D = 600 mm: eqs. 14–15 give [586.26, 614.40] mm, CoC ≤ c holds on
  [586.93, 613.70] mm = [DH/(D+H−f), D(H−2f)/(H−f−D)]).
- **Gaussian σ = CoC/2** (in pixels): the paper convolves "with a Gaussian kernel, where the
  kernel size is equal to the size of the circle of confusion"; we read the blur-spot diameter
  as 2σ. The kernel is truncated to the square window |dx|, |dy| ≤ R = ceil(3σ) and
  renormalised (also where the window is clipped by the image border).
- **Disk radius = CoC/2**: a uniform aperture (beyond the paper), antialiased weight
  clamp(r + 0.5 − |d|, 0, 1), window |dx|, |dy| ≤ ceil(r).
- **Gather**, not scatter: the output pixel's own σ (from its own depth) sets its kernel. This
  is what a one-texture-lookup-per-tap fragment shader can do; it blurs the in-focus side of a
  depth discontinuity less than a physical scatter would. Pixels without a surface (the
  background) are gathered at the background grey like any other pixel, and are never blurred
  themselves (σ = 0).
- **GL schemes** for the Gaussian (``optics.scheme``; the oracle is always ``blur_exact``):
  ``gather`` (the 2-D gather itself), ``hybrid`` (the separable pair where σ is constant over
  the pixel's column window, the 2-D gather elsewhere: ``blur_hybrid``), ``expansion`` (the
  default: rows blurred with their own σ and expanded to third order in 1/σ², moved to the
  output pixel's σ and window, a row gathered directly where the remainder bound exceeds
  ``EXPANSION_TOL``: ``blur_expansion``) and ``separable`` (the fast pair, inexact where σ
  varies: ``blur_separable``). The disk is always gathered in 2-D.
- Eq. 19 takes the similar triangles with apex at the sensor (V_D in the denominator); a thin
  lens has its apex at the image point V_P, which gives CoC = f²|P − D| / (N P (D − f)) (1 %
  smaller at P = 500 mm, D = 600 mm). We follow the paper.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

KERNELS = ("gaussian", "disk")
SCHEMES = ("expansion", "gather", "hybrid", "separable")   # GL's Gaussian; optics.scheme "auto" → expansion
TRUNCATE = 3.0  # the Gaussian is cut at R = ceil(TRUNCATE·σ)
EXP_CHORD = (np.e ** 2 - 1) / 2  # exp(x) ≤ 1 + EXP_CHORD·x on [0, 2]
EXPANSION_TOL = 1e-4  # expansion: bound on its error (fraction of the local grey range) before a row is gathered


def _param(optics, name, default=None):
    if isinstance(optics, Mapping):
        value = optics.get(name, default)
    else:
        value = getattr(optics, name, default)
    if value is None:
        raise ValueError(f"optics.{name} is missing — give it ({_UNITS[name]})")
    return value


_UNITS = {"focal_length": "mm", "f_number": "the f-number N", "focus_distance": "mm",
          "pixel_pitch": "mm per pixel", "coc_px": "pixels", "kernel": "'gaussian' or 'disk'"}


# ---------------------------------------------------------------------------- optics (14–19)

def hyperfocal(f, N, c_mm):
    """Hyperfocal distance H = f²/(N c) + f (eq. 16), mm."""
    return f * f / (N * c_mm) + f


def dof_limits(D, H):
    """Near and far limits of the depth of field (eqs. 14–15): D⁻ = DH/(H + D), D⁺ = DH/(H − D).

    D⁺ is finite only for D < H and infinite for D ≥ H (focused at or beyond the hyperfocal
    distance, everything from D⁻ on is sharp). The paper's text has the condition backwards
    ("only valid if H is smaller than D"): for H < D its formula would give a negative distance.
    Vectorised over D and H.
    """
    D = np.asarray(D, dtype=np.float64)
    H = np.asarray(H, dtype=np.float64)
    near = D * H / (H + D)
    with np.errstate(divide="ignore", invalid="ignore"):
        far = np.where(D < H, D * H / np.where(D < H, H - D, 1.0), np.inf)
    if near.ndim == 0:
        return float(near), float(far)
    return near, far


def coc_mm(P, D, f, N):
    """Blur-spot (circle of confusion) diameter in mm on the sensor of a point at distance P
    when focused at D (eqs. 17–19): V_D = fD/(D − f), V_P = fP/(P − f),
    CoC = |V_D − V_P|·f/(N·V_D).

    Evaluated in the algebraically equal form CoC = f²|P − D| / (N (P − f) D), which has no
    cancellation (V_D − V_P = f²(P − D)/((D − f)(P − f))); the GLSL twin uses the same form in
    float. Valid for P > f and D > f. Vectorised over P (and the others).
    """
    P = np.asarray(P, dtype=np.float64)
    return f * f * np.abs(P - D) / (N * (P - f) * D)


def coc_px(Z, optics):
    """Circle of confusion in pixels at camera-frame depth Z (mm): coc_mm / pixel_pitch."""
    return coc_mm(Z, _param(optics, "focus_distance"), _param(optics, "focal_length"),
                  _param(optics, "f_number")) / _param(optics, "pixel_pitch")


def check_depths(Z, optics, where: str = "the specimen") -> None:
    """SceneError naming ``optics.focal_length`` if a surface at camera-frame depth Z (mm; Z ≤ 0:
    no surface) is as close as the focal length or closer: a thin lens forms no real image of it."""
    Z = np.asarray(Z, dtype=np.float64)
    f = _param(optics, "focal_length")
    near = Z[(Z > 0) & (Z <= f)]
    if near.size:
        from glsim.errors import SceneError

        raise SceneError("optics.focal_length", f"{where} comes {near.min():.4g} mm from the lens, within its "
                         f"focal length of {f:g} mm: a lens forms no image of it",
                         "give the lens's real focal length (the camera's fx × pixel_pitch), or move the specimen "
                         "beyond it")


def _blur_size(Z, optics):
    """CoC/2 in pixels outside the in-focus band, 0 inside it and where Z ≤ 0."""
    Z = np.asarray(Z, dtype=np.float64)
    f = _param(optics, "focal_length")
    check_depths(Z, optics)
    surface = Z > 0
    c = coc_px(np.where(surface, Z, 2 * f + 1.0), optics)
    return np.where(surface & (c > _param(optics, "coc_px", 1.0)), 0.5 * c, 0.0)


def blur_sigma(Z, optics):
    """Gaussian σ (px) per pixel from its depth Z (mm): CoC_px/2 where CoC_px > optics.coc_px,
    0 inside the depth of field (CoC_px ≤ optics.coc_px: "appears in focus") and where Z ≤ 0
    (background, no surface). σ is half the blur-spot diameter (see the module docstring).
    Raises ValueError for 0 < Z ≤ f."""
    return _blur_size(Z, optics)


def blur_radius(Z, optics):
    """Disk-kernel radius (px): CoC_px/2 outside the depth of field, 0 inside it and for Z ≤ 0."""
    return _blur_size(Z, optics)


def kernel_radius(size, kernel="gaussian"):
    """Integer half-width of the window: ceil(3σ) (Gaussian) or ceil(r) (disk); 0 for size 0.
    The shaders need ``MAX_RADIUS`` ≥ kernel_radius(max size)."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    s = np.asarray(size, dtype=np.float64)
    return np.ceil((TRUNCATE if kernel == "gaussian" else 1.0) * s).astype(np.int64)


def shader_uniforms(optics) -> dict:
    """The float uniforms of ``shaders/dof.glsl`` (and ``blur.frag``'s expansion tolerance)."""
    return {"u_focal_length": float(_param(optics, "focal_length")),
            "u_f_number": float(_param(optics, "f_number")),
            "u_focus_distance": float(_param(optics, "focus_distance")),
            "u_pixel_pitch": float(_param(optics, "pixel_pitch")),
            "u_coc_px": float(_param(optics, "coc_px", 1.0)),
            "u_expansion_tol": EXPANSION_TOL}


def blur_scheme(optics) -> str:
    """The GL blur scheme of ``optics``: "disk" for the disk kernel (a 2-D gather), else its
    ``scheme`` with "auto" read as "expansion"."""
    kernel = _param(optics, "kernel", "gaussian")
    scheme = _param(optics, "scheme", "auto")
    if kernel == "disk":
        if scheme not in ("auto", "gather"):
            raise ValueError(f"optics.scheme {scheme!r} applies to the Gaussian kernel only")
        return "disk"
    if scheme == "auto":
        return "expansion"
    if scheme not in SCHEMES:
        raise ValueError(f"optics.scheme must be one of {('auto',) + SCHEMES}, got {scheme!r}")
    return scheme


def pixel_depth(z: np.ndarray, H: int, W: int, s: int) -> np.ndarray:
    """Per-pixel depth for the blur as the GL path holds it: each sample's depth rounded to
    float32 (the depth target), for s > 1 the mean over the covered (non-zero) samples summed
    in float32 in downsample.frag's order (rows j, then columns i). σ is then evaluated in
    float64 from the same float32 depth in both backends, so they draw the in-focus threshold
    and the window ceil(3σ) alike. Returns float64 (H, W), 0 where nothing is covered."""
    z32 = np.asarray(z, np.float32).reshape(H, s, W, s)
    if s == 1:
        return z32[:, 0, :, 0].astype(np.float64)
    acc = np.zeros((H, W), np.float32)
    n = np.zeros((H, W), np.float32)
    for j in range(s):
        for i in range(s):
            acc += z32[:, j, :, i]
            n += (z32[:, j, :, i] > 0).astype(np.float32)
    return np.divide(acc, n, out=np.zeros((H, W), np.float32), where=n > 0).astype(np.float64)


# ---------------------------------------------------------------------------- kernels

def gaussian_weights(d, sigma):
    """Unnormalised Gaussian weight exp(−d²/(2σ²)) for offset d (px); 0 beyond the truncation
    radius |d| > ceil(3σ). σ = 0 gives the identity exactly: 1 at d = 0, 0 elsewhere."""
    d, sigma = np.broadcast_arrays(np.asarray(d, dtype=np.float64), np.asarray(sigma, dtype=np.float64))
    safe = np.where(sigma > 0, sigma, 1.0)
    w = np.exp(-d * d / (2 * safe * safe))
    w = np.where(np.abs(d) <= kernel_radius(sigma), w, 0.0)
    return np.where(sigma > 0, w, (d == 0).astype(np.float64))


def _check(image, size_map, what):
    img = np.asarray(image, dtype=np.float64)
    s = np.asarray(size_map, dtype=np.float64)
    if img.ndim != 2 or s.shape != img.shape:
        raise ValueError(f"image and {what} map must be 2-D of the same shape, got "
                         f"{img.shape} and {s.shape}")
    if not np.all(np.isfinite(s)) or np.any(s < 0):
        raise ValueError(f"{what} map must be finite and ≥ 0")
    return img, s


def _windows(size, radius, shape, offsets_1d=None):
    """The gather's pixels and window offsets: (rows, cols, their sizes) of the pixels with size
    > 0, sorted by window radius (largest first), and an iterator over the offsets (dx, dy) of
    the largest window giving (dx, dy, n, r, c, ok) — the first n pixels (those whose window
    reaches the offset), the offset pixels' rows and columns, and whether they lie in the image
    of ``shape`` (H, W). ``offsets_1d`` = "x" or "y": only that axis' offsets."""
    rows, cols = np.nonzero(size > 0)
    if rows.size == 0:
        return rows, cols, np.zeros(0), iter(())
    R = radius[rows, cols]
    order = np.argsort(-R, kind="stable")
    rows, cols, R = rows[order], cols[order], R[order]
    H, W = shape
    Rmax = int(R[0])
    count = np.searchsorted(-R, -np.arange(Rmax + 1), side="right")  # pixels with R ≥ k

    def offsets():
        for dy in range(-Rmax, Rmax + 1):
            if offsets_1d == "x" and dy != 0:
                continue
            for dx in range(-Rmax, Rmax + 1):
                if offsets_1d == "y" and dx != 0:
                    continue
                n = count[max(abs(dx), abs(dy))]
                r, c = rows[:n] + dy, cols[:n] + dx
                yield dx, dy, n, r, c, (r >= 0) & (r < H) & (c >= 0) & (c < W)
    return rows, cols, size[rows, cols], offsets()


def _gather(img, size, radius, weight, offsets_1d=None):
    """out(p) = Σ_q w(dx, dy, size_p) img(q) / Σ_q w over the window |q − p|∞ ≤ radius_p clipped
    at the border; pixels with size 0 are copied. ``offsets_1d`` = "x" or "y" makes it 1-D.
    Pixels are sorted by radius so each offset ring touches only the pixels that reach it
    (:func:`_windows`)."""
    out = img.copy()
    H, W = img.shape
    rows, cols, s, offsets = _windows(size, radius, img.shape, offsets_1d)
    acc = np.zeros(rows.size)
    wsum = np.zeros(rows.size)
    for dx, dy, n, r, c, ok in offsets:
        w = weight(dx, dy, s[:n])
        w = np.where(ok, w, 0.0)
        acc[:n] += w * img[np.clip(r, 0, H - 1), np.clip(c, 0, W - 1)]
        wsum[:n] += w
    if rows.size:
        out[rows, cols] = acc / wsum
    return out


def _gauss(dx, dy, s):
    return np.exp(-float(dx * dx + dy * dy) / (2 * s * s))


def _disk(dx, dy, r):
    return np.clip(r + 0.5 - np.hypot(dx, dy), 0.0, 1.0)


def _dgauss(dx, dy, s):
    """∂/∂σ of :func:`_gauss`."""
    d2 = float(dx * dx + dy * dy)
    return np.exp(-d2 / (2 * s * s)) * d2 / (s * s * s)


def _ddisk(dx, dy, r):
    """∂/∂r of :func:`_disk` (1 on its ramp)."""
    t = r + 0.5 - np.hypot(dx, dy)
    return ((t > 0) & (t < 1)).astype(np.float64)


def gather_linearization(image, size_map, kernel: str = "gaussian"):
    """The oracle's gather blur (:func:`blur_exact`, :func:`blur_disk`) of ``image`` (H, W) with
    the per-pixel σ or radius ``size_map`` (px), linearised for image Jacobians: (C, d) — C a
    scipy CSR matrix (H·W × H·W), the blur of any image x with this size map being C·x.ravel()
    (unblurred pixels: the identity), and d (H·W,) ∂out/∂size at ``image`` (per px of σ or
    radius; 0 where the size is 0). The window is held (its radius jumps with the size)."""
    from scipy import sparse

    img, s = _check(image, size_map, "size")
    H, W = img.shape
    weight, dweight = (_gauss, _dgauss) if kernel == "gaussian" else (_disk, _ddisk)
    flat = img.ravel()
    still = np.flatnonzero(s.ravel() == 0)
    rows, cols, sz, offsets = _windows(s, kernel_radius(s, kernel), img.shape)
    d = np.zeros(H * W)
    if rows.size == 0:
        return sparse.identity(H * W, format="csr"), d
    acc, wsum, dacc, dwsum = (np.zeros(rows.size) for _ in range(4))
    at, to, val = [], [], []
    for dx, dy, n, r, c, ok in offsets:
        w, dw = np.where(ok, weight(dx, dy, sz[:n]), 0.0), np.where(ok, dweight(dx, dy, sz[:n]), 0.0)
        q = np.clip(r, 0, H - 1) * W + np.clip(c, 0, W - 1)
        acc[:n] += w * flat[q]
        wsum[:n] += w
        dacc[:n] += dw * flat[q]
        dwsum[:n] += dw
        k = np.flatnonzero(w)
        at.append(k)
        to.append(q[k])
        val.append(w[k])
    at = np.concatenate(at)
    pixel = rows * W + cols
    d[pixel] = (dacc - acc / wsum * dwsum) / wsum
    C = sparse.csr_matrix((np.concatenate([np.concatenate(val) / wsum[at], np.ones(still.size)]),
                           (np.concatenate([pixel[at], still]), np.concatenate([np.concatenate(to), still]))),
                          shape=(H * W, H * W))
    return C, d


def coc_slope(Z, optics):
    """|∂CoC_px/∂Z| (px per mm) at camera-frame depths Z > f (mm): of f²|Z − D| / (N (Z − f) D ·
    pitch), f²(D − f) / (N D (Z − f)² · pitch) on either side of the focus."""
    Z = np.asarray(Z, dtype=np.float64)
    f, D, N, pitch = (_param(optics, k) for k in ("focal_length", "focus_distance", "f_number", "pixel_pitch"))
    return f * f * abs(D - f) / (N * D * (Z - f) ** 2 * pitch)


def size_derivative(Z, optics):
    """∂(blur σ or disk radius)/∂Z (px per mm) at camera-frame depths Z (mm): of CoC_px/2,
    sign(Z − D)·:func:`coc_slope`/2, where the pixel is blurred (:func:`blur_sigma` > 0), else 0."""
    Z = np.asarray(Z, dtype=np.float64)
    f, D = _param(optics, "focal_length"), _param(optics, "focus_distance")
    blurred = _blur_size(Z, optics) > 0
    Zs = np.where(blurred, Z, 2 * f + 1.0)
    return np.where(blurred, np.sign(Zs - D) * coc_slope(Zs, optics) / 2, 0.0)


def blur_exact(image, sigma_map):
    """The oracle: spatially varying Gaussian *gather* with the output pixel's σ,
    out(p) = Σ_q w(|q − p|; σ_p) I(q) / Σ_q w, over the square window |q − p|∞ ≤ ceil(3σ_p)
    clipped at the image border (renormalised). Pixels with σ_p = 0 are copied exactly.
    Returns float64."""
    img, s = _check(image, sigma_map, "sigma")
    return _gather(img, s, kernel_radius(s), _gauss)


def blur_separable(image, sigma_map):
    """numpy mirror of ``blur.frag``'s BLUR_HORIZONTAL then BLUR_VERTICAL passes: a 1-D
    horizontal gather with the output pixel's σ, then a 1-D vertical gather of that result with
    the output pixel's σ (each renormalised, clipped at the border; σ_p = 0 copies).

    Equal to ``blur_exact`` where σ is constant over the window (the truncated Gaussian on a
    square window is a product); elsewhere the vertical pass mixes rows that were blurred
    horizontally with their own σ — the separable approximation's error (tests/test_blur.py
    measures it on a tilted plate). Returns float64."""
    img, s = _check(image, sigma_map, "sigma")
    R = kernel_radius(s)
    h = _gather(img, s, R, _gauss, offsets_1d="x")
    return _gather(h, s, R, _gauss, offsets_1d="y")


def blur_disk(image, radius_map):
    """Uniform-aperture (disk) blur, beyond the paper: 2-D gather with the antialiased weight
    clamp(r_p + 0.5 − |q − p|, 0, 1) of the output pixel's radius r_p, renormalised, clipped at
    the border; r_p = 0 copies the pixel exactly. Not separable. Returns float64."""
    img, r = _check(image, radius_map, "radius")
    return _gather(img, r, kernel_radius(r, "disk"), _disk)


def varying_columns(sigma_map):
    """Pixels (σ > 0) whose column window |dy| ≤ ceil(3σ) (clipped at the border) holds a σ
    other than their own: where ``hybrid`` gathers in 2-D (a min/max filter of σ along the
    column). The separable pair is exact at every other pixel."""
    s = np.asarray(sigma_map, dtype=np.float64)
    H = s.shape[0]
    R = kernel_radius(s)
    out = np.zeros(s.shape, bool)
    y = np.arange(H)[:, None]
    for dy in range(-int(R.max(initial=0)), int(R.max(initial=0)) + 1):
        q = np.clip(y + dy, 0, H - 1)[:, 0]
        out |= (np.abs(dy) <= R) & (y + dy >= 0) & (y + dy < H) & (s[q] != s)
    return out & (s > 0)


def blur_hybrid(image, sigma_map):
    """numpy mirror of the ``hybrid`` scheme: the separable pair where σ is constant over the
    column window (there it equals ``blur_exact``: the window is a product and every row it
    reads was blurred with the output pixel's σ), the 2-D gather at ``varying_columns``.
    Equal to ``blur_exact`` up to rounding. Returns float64."""
    img, s = _check(image, sigma_map, "sigma")
    return np.where(varying_columns(s), blur_exact(img, s), blur_separable(img, s))


def row_moments(image, sigma_map):
    """The ``expansion`` scheme's first pass (``blur.frag`` BLUR_ROWS), float64: per pixel q
    with σ_q > 0 and c_q = −1/(2σ_q²), over its row window |k| ≤ R_q = ceil(3σ_q) clipped at
    the border, the moments M_n = Σ_k e^{c_q k²} k^{2n} (I(q + k) − I(q)), n = 0…3, and the
    remainder factor F·Σ_k e^{c_q k²} k⁸ with F = max_k |I(q + k) − I(q)|.
    Returns (M (4, H, W), bound (H, W)); zeros where σ_q = 0."""
    img, s = _check(image, sigma_map, "sigma")
    W = img.shape[1]
    R = kernel_radius(s)
    c = -0.5 / np.where(s > 0, s, 1.0) ** 2
    M = np.zeros((4,) + img.shape)
    N4 = np.zeros(img.shape)
    F = np.zeros(img.shape)
    x = np.arange(W)
    Rm = int(R.max(initial=0))
    for k in range(-Rm, Rm + 1):
        ok = (abs(k) <= R) & ((x + k >= 0) & (x + k < W))[None, :] & (s > 0)
        f = np.where(ok, img[:, np.clip(x + k, 0, W - 1)] - img, 0.0)
        w = np.where(ok, np.exp(c * k * k), 0.0)
        kk = float(k * k)
        for n in range(4):
            M[n] += w * kk ** n * f
        N4 += w * kk ** 4
        F = np.maximum(F, np.abs(f))
    return M, F * N4


def blur_expansion(image, sigma_map, tol: float = EXPANSION_TOL, stats: dict | None = None):
    """numpy mirror of the ``expansion`` scheme (``blur.frag`` BLUR_ROWS, BLUR_COLUMNS), float64.

    The 2-D gather of pixel p is Σ_dy v(dy) r(p.y + dy) / (Σ v · B_p) with v the column
    weights of σ_p, r(q) = Σ_k e^{c_p k²} I(q + k) the row sum with p's weight c_p = −1/(2σ_p²)
    and window R_p, and B_p = Σ_k e^{c_p k²} (both clipped at the border). Each row sum is
    taken from that row pixel's own ``row_moments`` (weight c_q, window R_q) by the Taylor
    expansion e^{(c_p − c_q) k²} ≈ Σ_{n≤3} ((c_p − c_q) k²)ⁿ / n!, plus (minus) the taps between
    R_q and R_p with their exact weights. Lagrange's remainder bounds the row's error by
    |c_p − c_q|⁴ e^{g} F Σ e^{c_q k²} k⁸ / 24, g = max(c_p − c_q, 0) R_q², with e^g taken as
    its chord 1 + g (e² − 1)/2 on [0, 2]; where that bound times v(dy) / Σ v exceeds ``tol`` ·
    B_p / (2 R_p + 1), where g > 2, and in rows without σ (background, in focus), the row is
    summed directly. The result is then within ``tol`` of ``blur_exact``
    (as a fraction of the rows' grey range F). ``stats`` (a dict) receives the fraction of
    rows summed directly. Returns float64."""
    img, s = _check(image, sigma_map, "sigma")
    H, W = img.shape
    R = kernel_radius(s)
    Rm = int(R.max(initial=0))
    if Rm == 0:
        return img.copy()
    M, FN = row_moments(img, s)
    c = -0.5 / np.where(s > 0, s, 1.0) ** 2
    x, y = np.arange(W)[None, :], np.arange(H)[:, None]
    Bp = np.zeros(img.shape)
    Bv = np.zeros(img.shape)
    for k in range(-Rm, Rm + 1):
        w = np.exp(c * k * k) * (abs(k) <= R)
        Bp += np.where((x + k >= 0) & (x + k < W), w, 0.0)
        Bv += np.where((y + k >= 0) & (y + k < H), w, 0.0)
    budget = tol * Bp * Bv / (2 * R + 1)
    acc = np.zeros(img.shape)
    direct_rows = 0
    for dy in range(-Rm, Rm + 1):
        qy = np.clip(y[:, 0] + dy, 0, H - 1)
        row_in = (abs(dy) <= R) & (y + dy >= 0) & (y + dy < H) & (s > 0)
        v = np.where(row_in, np.exp(c * dy * dy), 0.0)
        sq, Rq, Iq = s[qy], R[qy], img[qy]
        dc = c - np.where(sq > 0, c[qy], 0.0)
        with np.errstate(over="ignore", invalid="ignore"):
            grow = np.maximum(dc, 0) * Rq * Rq
            bound = dc ** 4 * FN[qy] * (1 + EXP_CHORD * grow) / 24    # e^grow ≤ its chord on [0, 2]
            use = (sq > 0) & (grow <= 2.0) & (v * bound <= budget)
        A = M[0][qy] + dc * (M[1][qy] + dc * (M[2][qy] / 2 + dc * M[3][qy] / 6))
        direct = np.zeros(img.shape)
        for k in range(-Rm, Rm + 1):
            inside = (x + k >= 0) & (x + k < W)
            fk = np.where(inside, Iq[:, np.clip(x[0] + k, 0, W - 1)] - Iq, 0.0)
            wk = np.exp(c * k * k)
            A += wk * fk * (((abs(k) > Rq) & (abs(k) <= R)).astype(float) - ((abs(k) > R) & (abs(k) <= Rq)))
            direct += np.where(abs(k) <= R, wk * fk, 0.0)
        A = np.where(use, A, direct)
        direct_rows += int((row_in & ~use).sum())
        acc += v * (Iq * Bp + A)
    if stats is not None:
        stats["direct_rows"] = direct_rows / max(1, int(np.where(s > 0, 2 * R + 1, 0).sum()))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s > 0, acc / (Bv * Bp), img)


def through_blur(J, J_depth, image: np.ndarray, depth: np.ndarray, optics):
    """The derivative of the depth of field: an image Jacobian ``J`` (W·H × n, sparse) of the
    image before the blur → of the blurred image (the oracle's gather, :func:`gather_linearization`),
    given the derivative of each pixel's depth ``J_depth`` (W·H × n, mm per unit), the unblurred
    ``image`` (H, W) and the depths (H, W) mm the blur's sizes come from:
    C·J + diag(∂out/∂size · ∂size/∂Z)·J_depth. SceneError naming [optics] where C·J would need
    more memory than this process may use (its entries estimated from every k-th row's)."""
    from scipy import sparse

    from glsim.errors import SceneError
    from glsim.limits import memory_budget

    size = blur_sigma(depth, optics)
    C, d = gather_linearization(image, size, optics.kernel)
    probe = np.arange(0, C.shape[0], max(1, C.shape[0] // 4096))   # C·J's entries per row, on every k-th row
    need, budget = 24 * ((C[probe] @ J).nnz * C.shape[0] // len(probe) + C.nnz), memory_budget()
    if need > budget:
        raise SceneError("optics", f"the image Jacobian through the depth of field's blur (up to "
                         f"{2 * int(kernel_radius(size.max(), optics.kernel)) + 1} px windows) needs about "
                         f"{need / 2**30:.3g} GiB, more than the {budget / 2**30:.3g} GiB this process may use",
                         "render a smaller camera (a region of interest), or render without jacobian")
    return sparse.csr_matrix(C @ J + sparse.diags(d * size_derivative(depth, optics).ravel()) @ J_depth)
