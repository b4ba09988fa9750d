"""The dot model fit, the default dot-centre estimator (``method="fit"``, :func:`fit_ellipses`):
within ``EDGE_BAND`` px of its edge (the band sized from the dot, not from the grid pitch), a
dot's grey levels are I = b + C·F(d), d the pixel centre's signed distance from an ellipse
(centre, 2×2 shape) and F the exact fraction of the pixel square inside a straight edge at that
distance and orientation, blurred by a Gaussian of fitted σ (:func:`edge_profile`).
Levenberg–Marquardt fits all dots of an image at once (8 parameters each). The perspective
image of a circle is an ellipse, whose centre is its area centroid; lens distortion bends it
slightly, which moves the fitted centre from the area centroid by < 1e-4 px for the Table 8
rig. Pixels away from the edge carry no information on the centre, so leaving them out removes
the noise they add to a grey-level centroid: at every noise level the fit reaches the
Cramér–Rao bound of the image (:func:`centre_bound`; docs/calib.md, bench/results/calib_detection.md).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

WINDOW = 0.45          # half-width of the start (and centroid) window, in local grid spacings
EDGE_BAND = 4.0        # px each side of a dot's edge that its model fit uses
FIT_ROUNDS = 2         # model fits, each choosing the band pixels anew
FIT_ITERATIONS = 12    # Levenberg–Marquardt steps per fit
MIN_EDGE = 0.02        # px, the least blur σ of the fit (a sharp edge's profile is the pixel's)


@dataclass(frozen=True, eq=False)
class Ellipses:
    """Fitted dots (N rows, NaN where lost): ``centres`` (N, 2) px, ``M`` (N, 2, 2) with the
    dot's edge {p: (p − c)ᵀ·M·(p − c) = 1}, ``background`` and ``contrast`` (grey, contrast
    signed: > 0 for white dots), ``edge`` (N,) the σ of the edge's Gaussian profile (px),
    ``rms`` (N,) the fit's residual RMS (grey)."""
    centres: np.ndarray
    M: np.ndarray
    background: np.ndarray
    contrast: np.ndarray
    edge: np.ndarray
    rms: np.ndarray

    @property
    def areas(self) -> np.ndarray:
        """Area inside each edge, px²."""
        with np.errstate(invalid="ignore"):
            return np.pi / np.sqrt(np.linalg.det(self.M))


def window_pixels(image, centre, e_col, e_row, window):
    """Pixel coordinates (n, 2), grey levels (n,) and parallelogram norm (n,) of the window of
    ±``window`` grid vectors around ``centre``, or None where it leaves the image."""
    A = np.stack([e_col, e_row], axis=1)
    if not np.all(np.isfinite(A)) or not np.all(np.isfinite(centre)) or not abs(np.linalg.det(A)) > 1e-6:
        return None
    corners = centre + (A @ np.array([[-1, -1, 1, 1], [-1, 1, -1, 1]]) * window).T
    u0, v0 = np.floor(corners.min(0)).astype(int)
    u1, v1 = np.ceil(corners.max(0)).astype(int)
    H, W = image.shape
    if u0 < 0 or v0 < 0 or u1 >= W or v1 >= H:
        return None
    uu, vv = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
    p = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    m = np.abs(np.linalg.solve(A, (p - centre).T).T).max(axis=1)
    inside = m <= window
    return p[inside], image[v0:v1 + 1, u0:u1 + 1].ravel()[inside], m[inside]


def initial_ellipses(image: np.ndarray, points: np.ndarray, e_col: np.ndarray, e_row: np.ndarray,
                     white: bool, ring: float, window: float = WINDOW) -> Ellipses:
    """Start values of the model fit from the pixels beyond half contrast in each dot's window
    (±``window`` local grid vectors): their centroid and second moments (a uniform ellipse has
    covariance Σ = M⁻¹/4), the background (median of the window beyond ``ring``) and the
    dot's level (median of the pixels inside half the ellipse)."""
    n = len(points)
    c = np.full((n, 2), np.nan)
    M = np.full((n, 2, 2), np.nan)
    b = np.full(n, np.nan)
    C = np.full(n, np.nan)
    for k in range(n):
        w = window_pixels(image, points[k], e_col[k], e_row[k], window)
        if w is None:
            continue
        p, I, m = w
        bg = np.median(I[m >= ring])
        sign = 1.0 if white else -1.0
        peak = np.percentile(sign * (I - bg), 95)
        if not peak > 0:
            continue
        on = sign * (I - bg) > peak / 2
        if on.sum() < 5:
            continue
        q = p[on]
        centre = q.mean(0)
        cov = np.cov(q.T, bias=True) + np.eye(2) / 12
        if not np.linalg.det(cov) > 0:
            continue
        Mk = np.linalg.inv(4 * cov)
        r = p - centre
        inner = np.einsum("ni,ij,nj->n", r, Mk, r) < 0.25
        if not inner.any():
            continue
        c[k], M[k], b[k], C[k] = centre, Mk, bg, np.median(I[inner]) - bg
    return Ellipses(c, M, b, C, np.full(n, 0.7), np.full(n, np.nan))


def _edge_distance(P, c, m):
    """Signed distance of pixels P (N, K, 2) from the ellipses (c (N, 2), m (N, 3) = m11, m12,
    m22; > 0 outside), to second order in the distance (exact for circles: the first-order
    distance (g − 1)/|∇g| of the level set g = √(rᵀMr) = 1, corrected by the curvature of g
    along its gradient), and the first-order distance's derivatives (N, K, 5) by cx, cy, m11,
    m12, m22. Also g (N, K)."""
    rx, ry = P[..., 0] - c[:, None, 0], P[..., 1] - c[:, None, 1]
    m11, m12, m22 = (m[:, i, None] for i in range(3))
    vx, vy = m11 * rx + m12 * ry, m12 * rx + m22 * ry
    q = rx * vx + ry * vy
    g = np.sqrt(np.maximum(q, 1e-12))
    n = np.maximum(np.hypot(vx, vy), 1e-12)
    d = (q - g) / n
    a = 1 - 1 / (2 * g)
    Mvx, Mvy = m11 * vx + m12 * vy, m12 * vx + m22 * vy
    dq = np.stack([-2 * vx, -2 * vy, rx * rx, 2 * rx * ry, ry * ry], axis=-1)
    dn = np.stack([-Mvx / n, -Mvy / n, vx * rx / n, (vx * ry + vy * rx) / n, vy * ry / n], axis=-1)
    dd = (a[..., None] * dq - d[..., None] * dn) / n[..., None]
    h = ((vx * Mvx + vy * Mvy) / (n * n) - (n * n) / (g * g)) / g      # n̂ᵀ·Hess(g)·n̂
    return d - 0.5 * d * d * h * g / n, g, dd


def _gauss_terms(x, s):
    """Φ(x/s), Ψ1 = ∫Φ = x·Φ + s·φ and Ψ2 = ∫Ψ1 = ½(x² + s²)·Φ + ½·x·s·φ (φ, Φ: the standard
    normal's density and CDF at x/s)."""
    from scipy.special import ndtr
    z = x / s
    Phi = ndtr(z)
    phi = np.exp(-0.5 * z * z) * (1 / np.sqrt(2 * np.pi))
    return Phi, x * Phi + s * phi, 0.5 * (x * x + s * s) * Phi + 0.5 * x * s * phi


def edge_profile(t, a, b, s, derivatives: bool = False):
    """Fraction of a pixel inside a straight edge whose normal has components ``a`` ≥ ``b`` ≥ 0
    (a² + b² = 1) in pixel axes, ``t`` px from the pixel centre to the edge (> 0: the centre is
    inside), blurred by a Gaussian of σ = ``s`` px: the CDF at t of a·U₁ + b·U₂ + s·Z (the unit
    pixel square projected on the normal, U uniform on ±½, Z standard normal), a second
    difference of Ψ2. With ``derivatives``: (F, ∂F/∂t, ∂F/∂a, ∂F/∂b, ∂F/∂s)."""
    thin = b < 1e-3                                   # a·U₁ + s·Z alone (the limit b → 0)
    b = np.where(thin, 1.0, b)
    xs = (t + (a + b) / 2, t + (a - b) / 2, t - (a - b) / 2, t - (a + b) / 2)
    sign = (1, -1, -1, 1)
    terms = [_gauss_terms(x, s) for x in xs]
    ab = a * b
    F = sum(g * T[2] for g, T in zip(sign, terms)) / ab
    ta = [_gauss_terms(x, s) for x in (t + a / 2, t - a / 2)]
    F_thin = (ta[0][1] - ta[1][1]) / a
    F = np.where(thin, F_thin, F)
    if not derivatives:
        return F
    P1 = [T[1] for T in terms]
    Ft = sum(g * q for g, q in zip(sign, P1)) / ab
    Fs = s * sum(g * T[0] for g, T in zip(sign, terms)) / ab
    Fa = 0.5 * (P1[0] - P1[1] + P1[2] - P1[3]) / ab - F / a
    Fb = 0.5 * (P1[0] + P1[1] - P1[2] - P1[3]) / ab - F / b
    phia = [np.exp(-0.5 * (x / s) ** 2) / np.sqrt(2 * np.pi) for x in (t + a / 2, t - a / 2)]
    Ft = np.where(thin, (ta[0][0] - ta[1][0]) / a, Ft)
    Fs = np.where(thin, (phia[0] - phia[1]) / a, Fs)
    Fa = np.where(thin, 0.5 * (ta[0][0] + ta[1][0]) / a - F_thin / a, Fa)
    Fb = np.where(thin, 0.0, Fb)
    return F, Ft, Fa, Fb, Fs


def _model(P, I, mask, theta, jacobian: bool = True):
    """Residuals (N, K) and Jacobian (N, K, 8) of the dot model I = b + C·coverage for
    θ = (cx, cy, m11, m12, m22, b, C, s); coverage is :func:`edge_profile` at the pixel's
    signed distance d from the ellipse, with the pixel square projected on the ellipse's
    normal there."""
    c, m = theta[:, :2], theta[:, 2:5]
    d, g, dd = _edge_distance(P, c, m)
    rx, ry = P[..., 0] - c[:, None, 0], P[..., 1] - c[:, None, 1]
    m11, m12, m22 = (m[:, i, None] for i in range(3))
    vx, vy = m11 * rx + m12 * ry, m12 * rx + m22 * ry
    nv = np.maximum(np.hypot(vx, vy), 1e-300)
    ux, uy = np.abs(vx) / nv, np.abs(vy) / nv
    xbig = ux >= uy
    a, b = np.where(xbig, ux, uy), np.where(xbig, uy, ux)
    bg, C, s = theta[:, 5, None], theta[:, 6, None], theta[:, 7, None]
    out = edge_profile(-d, a, b, s, derivatives=jacobian)
    cover = out[0] if jacobian else out
    res = np.where(mask, I - (bg + C * cover), 0.0)
    if not jacobian:
        return res, None
    _, Ft, Fa, Fb, Fs = out
    # derivatives of the unit normal's |components| by v, then by the parameters through v
    sx, sy = np.sign(vx), np.sign(vy)
    # ∂|ûx|/∂v = sx (e_x − ûx·û)/|v|, ∂|ûy|/∂v = sy (e_y − ûy·û)/|v|  (û = v/|v|, signed)
    hx, hy = vx / nv, vy / nv
    dux = (sx * (1 - hx * hx) / nv, sx * (-hx * hy) / nv)
    duy = (sy * (-hy * hx) / nv, sy * (1 - hy * hy) / nv)
    da = tuple(np.where(xbig, p, q) for p, q in zip(dux, duy))
    db = tuple(np.where(xbig, q, p) for p, q in zip(dux, duy))
    # ∂v/∂θ for θ = cx, cy, m11, m12, m22
    zero = np.zeros_like(rx)
    dv = ((-m11 + zero, -m12 + zero), (-m12 + zero, -m22 + zero), (rx, zero), (ry, rx), (zero, ry))
    J = np.empty(P.shape[:2] + (8,))
    for j, (dvx, dvy) in enumerate(dv):
        dA = da[0] * dvx + da[1] * dvy
        dB = db[0] * dvx + db[1] * dvy
        J[..., j] = C * (-Ft * dd[..., j] + Fa * dA + Fb * dB)
    J[..., 5] = 1.0
    J[..., 6] = cover
    J[..., 7] = C * Fs
    return res, np.where(mask[..., None], J, 0.0)


def band_pixels(image, e: Ellipses, k: int, band: float, inner: bool = True):
    """Pixels within ``band`` px of dot k's current edge: (coords (n, 2), grey (n,)) or None
    where the band leaves the image. ``inner=False``: every pixel inside the edge as well, and
    their distances (n,) as a third item."""
    Minv = np.linalg.inv(e.M[k])
    half = np.sqrt(np.diag(Minv)) + band + 1
    u0, v0 = np.floor(e.centres[k] - half).astype(int)
    u1, v1 = np.ceil(e.centres[k] + half).astype(int)
    H, W = image.shape
    if u0 < 0 or v0 < 0 or u1 >= W or v1 >= H:
        return None
    uu, vv = np.meshgrid(np.arange(u0, u1 + 1), np.arange(v0, v1 + 1))
    p = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    m = e.M[k]
    d, g, _ = _edge_distance(p[None], e.centres[k][None], np.array([[m[0, 0], m[0, 1], m[1, 1]]]))
    if not inner:
        keep = d[0] <= band
        return p[keep], image[v0:v1 + 1, u0:u1 + 1].ravel()[keep], d[0][keep]
    keep = (np.abs(d[0]) <= band) & (g[0] > 0.3)
    return p[keep], image[v0:v1 + 1, u0:u1 + 1].ravel()[keep]


def fit_ellipses(image: np.ndarray, start: Ellipses, white: bool, band=EDGE_BAND,
                 rounds: int = FIT_ROUNDS, iterations: int = FIT_ITERATIONS) -> Ellipses:
    """Fit every dot's grey levels within ``band`` px (a number, or one per dot) of its edge
    with the model of the module text, I = b + C·F(d) (Levenberg–Marquardt on cx, cy, M, b,
    C, s, all dots at once), starting from ``start``. The band is chosen anew from the result
    of each of ``rounds``. A dot is lost (NaN) when its band leaves the image or the fit gives
    no ellipse of the right contrast near its start."""
    n = len(start.centres)
    band = np.broadcast_to(np.asarray(band, float), (n,))
    e = start
    ok = np.all(np.isfinite(e.centres), axis=1) & np.all(np.isfinite(e.M), axis=(1, 2))
    theta = np.column_stack([e.centres, e.M[:, 0, 0], e.M[:, 0, 1], e.M[:, 1, 1], e.background, e.contrast, e.edge])
    rms = np.full(n, np.nan)
    for _ in range(rounds):
        pix = {}
        for k in np.flatnonzero(ok):
            bp = band_pixels(image, e, k, band[k]) if band[k] >= 1.0 else None
            if bp is None or len(bp[1]) < 12:
                ok[k] = False
            else:
                pix[k] = bp
        idx = np.array(sorted(pix), dtype=int)
        if not len(idx):
            break
        K = max(len(pix[k][1]) for k in idx)
        P = np.zeros((len(idx), K, 2))
        I = np.zeros((len(idx), K))
        mask = np.zeros((len(idx), K), bool)
        for j, k in enumerate(idx):
            p, g = pix[k]
            P[j, :len(g)], I[j, :len(g)], mask[j, :len(g)] = p, g, True
        th = theta[idx].copy()
        lam = np.full(len(idx), 1e-3)
        res, J = _model(P, I, mask, th)
        sse = (res ** 2).sum(1)
        eye = np.eye(8)
        for _ in range(iterations):
            Jt = J.transpose(0, 2, 1)
            A = Jt @ J
            g = (Jt @ res[..., None])[..., 0]
            D = np.einsum("nii->ni", A)
            step = np.linalg.solve(A + lam[:, None, None] * (D[:, :, None] * eye + 1e-18 * eye), g[..., None])[..., 0]
            trial = th + step
            trial[:, 7] = np.clip(trial[:, 7], MIN_EDGE, 5.0)
            r2, J2 = _model(P, I, mask, trial)
            s2 = (r2 ** 2).sum(1)
            better = np.isfinite(s2) & (s2 <= sse)
            th[better], res[better], J[better], sse[better] = trial[better], r2[better], J2[better], s2[better]
            lam = np.where(better, lam / 10, lam * 10).clip(1e-9, 1e9)
        theta[idx] = th
        rms[idx] = np.sqrt(sse / mask.sum(1))
        M = np.stack([np.stack([theta[:, 2], theta[:, 3]], -1), np.stack([theta[:, 3], theta[:, 4]], -1)], -2)
        e = Ellipses(theta[:, :2].copy(), M, theta[:, 5].copy(), theta[:, 6].copy(), theta[:, 7].copy(), rms.copy())
        with np.errstate(invalid="ignore"):
            det = theta[:, 2] * theta[:, 4] - theta[:, 3] ** 2
            r0 = 1 / np.sqrt(np.sqrt(np.abs(np.linalg.det(np.where(np.isfinite(start.M), start.M, np.eye(2))))))
            ok &= (theta[:, 2] > 0) & (det > 0) & (np.sign(theta[:, 6]) == (1 if white else -1)) & \
                (theta[:, 7] < 5) & \
                (np.linalg.norm(theta[:, :2] - start.centres, axis=1) < 0.5 * r0)
    nan = ~ok
    e.centres[nan], e.M[nan], e.background[nan], e.contrast[nan], e.edge[nan], e.rms[nan] = np.nan, np.nan, np.nan, \
        np.nan, np.nan, np.nan
    return e


def centre_bound(image: np.ndarray, e: Ellipses, sigma: float, band=EDGE_BAND) -> np.ndarray:
    """The Cramér–Rao bound of each dot's centre (N, 2, 2 covariance, px²; NaN where lost) for
    white noise of σ = ``sigma`` (grey, full scale) on ``image``: (JᵀJ/σ²)⁻¹ of the model of
    :func:`fit_ellipses` at the fitted ``e`` over its band. No unbiased estimator of a dot's
    centre from these pixels does better."""
    n = len(e.centres)
    band = np.broadcast_to(np.asarray(band, float), (n,))
    out = np.full((n, 2, 2), np.nan)
    for k in np.flatnonzero(np.isfinite(e.centres[:, 0])):
        bp = band_pixels(image, e, k, band[k])
        if bp is None:
            continue
        th = np.array([[*e.centres[k], e.M[k, 0, 0], e.M[k, 0, 1], e.M[k, 1, 1], e.background[k], e.contrast[k],
                        e.edge[k]]])
        _, J = _model(bp[0][None], bp[1][None], np.ones((1, len(bp[1])), bool), th)
        out[k] = np.linalg.inv(J[0].T @ J[0])[:2, :2] * sigma ** 2
    return out


def mean_norm(cov: np.ndarray) -> np.ndarray:
    """E|x| for x ~ N(0, cov), cov (..., 2, 2) (Gauss–Hermite quadrature, 24 × 24 nodes)."""
    z, w = np.polynomial.hermite_e.hermegauss(24)
    w = w / w.sum()
    lam = np.clip(np.linalg.eigvalsh(cov), 0, None)
    r = np.sqrt(lam[..., 0, None, None] * z[:, None] ** 2 + lam[..., 1, None, None] * z[None, :] ** 2)
    return (r * w[:, None] * w[None, :]).sum(axis=(-1, -2))
