"""Target detection. Dot grids: cv2.findCirclesGrid with a SimpleBlobDetector tuned to the
image's grey levels finds and orders the grid (or, where the image border cuts it, the markers
anchor the dots in view: :func:`find_partial_grid`); every dot's centre is then measured by a
model fit to the grey levels near its edge; markers and handedness give the grid's
orientation; a grid with a dot off its neighbours' homography is rejected (:func:`inconsistent`).
Chessboards and ChArUco boards: OpenCV's detectors, corners put in the target's order.

The model fit (``method="fit"``, the default, :func:`fit_ellipses`): within ``EDGE_BAND`` px
of its edge (the band sized from the dot, not from the grid pitch), a dot's grey levels are
I = b + C·F(d), d the pixel centre's signed distance from an ellipse (centre, 2×2 shape) and
F the exact fraction of the pixel square inside a straight edge at that distance and
orientation, blurred by a Gaussian of fitted σ (:func:`edge_profile`). Levenberg–Marquardt
fits all dots of an image at once (8 parameters each). The perspective image of a circle is
an ellipse, whose centre is its area centroid; lens distortion bends it slightly, which moves
the fitted centre from the area centroid by < 1e-4 px for the Table 8 rig. Pixels away from
the edge carry no information on the centre, so leaving them out removes the noise they add to
a grey-level centroid: at every noise level the fit reaches the Cramér–Rao bound of the image
(:func:`centre_bound`; docs/calib.md, bench/results/calib_detection.md).

Other estimators, kept for the comparison (``METHODS``): ``centroid`` Σ(I − b)·p / Σ(I − b)
over ±0.45 local grid spacings (b: the window's outer ring; iterated, re-centred);
``centroid-dot`` the same over the dot's ellipse grown by 3 px; ``edge-ellipse`` an ellipse
fitted to sub-pixel edge points (half-contrast crossings along rays); ``blob`` OpenCV's blob
centres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glsim.errors import SceneError
from glsim.workflows.calib.targets import Charuco, Chessboard, DotGrid

WINDOW = 0.45          # half-width of the start (and centroid) window, in local grid spacings
ITERATIONS = 4         # centroid passes, each re-centring the window
MARKER_TOLERANCE = 0.35  # |log(measured/expected area ratio)| below which a marker cell agrees
REGULARITY = 0.4       # largest second difference of a found grid, in grid spacings
EDGE_BAND = 4.0        # px each side of a dot's edge that its model fit uses
FIT_ROUNDS = 2         # model fits, each choosing the band pixels anew
FIT_ITERATIONS = 12    # Levenberg–Marquardt steps per fit
MIN_EDGE = 0.02        # px, the least blur σ of the fit (a sharp edge's profile is the pixel's)
METHODS = ("fit", "centroid", "centroid-dot", "edge-ellipse", "blob")
VERSION = 4            # of the detector's results (detection caches made by another version are not used)


@dataclass(frozen=True, eq=False)
class Detection:
    """Dots found in one image, in the target's point order (row-major).

    ``points`` (N, 2) px: refined centres, NaN where a dot was not found or could not be
    measured (its window left the image); ``blobs`` (N, 2) px: the blob centres (corners for
    boards), same order; ``ok`` (N,) bool.
    """
    points: np.ndarray
    blobs: np.ndarray
    ok: np.ndarray


def to_unit(image: np.ndarray, bit_depth: int | None = None) -> np.ndarray:
    """An image as float64 grey levels in [0, 1] of full scale: floats are kept, integers
    divided by 2^bit_depth − 1 (default: 8 for uint8, 16 otherwise)."""
    image = np.asarray(image)
    if image.ndim != 2:
        raise SceneError("image", f"shape {image.shape} is not (H, W)", "give a greyscale image")
    if np.issubdtype(image.dtype, np.floating):
        return image.astype(np.float64)
    bits = bit_depth or (8 if image.dtype == np.uint8 else 16)
    return image.astype(np.float64) / ((1 << bits) - 1)


def blob_detector(image: np.ndarray, white: bool):
    """A SimpleBlobDetector for ``image`` (float, [0, 1]): thresholds spread over the middle
    half between the two Otsu class means, so noisy dots do not fragment near either level."""
    import cv2
    img8 = np.clip(np.rint(image * 255), 0, 255).astype(np.uint8)
    t, _ = cv2.threshold(img8, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    lo, hi = img8[img8 <= t].mean(), img8[img8 > t].mean() if np.any(img8 > t) else 255.0
    p = cv2.SimpleBlobDetector_Params()
    p.minThreshold, p.maxThreshold = float(lo + 0.25 * (hi - lo)), float(lo + 0.75 * (hi - lo))
    p.thresholdStep = max((p.maxThreshold - p.minThreshold) / 6, 1.0)
    p.minRepeatability = 2
    p.filterByColor, p.blobColor = True, 255 if white else 0
    p.filterByArea, p.minArea, p.maxArea = True, 4.0, image.size / 20
    p.filterByCircularity, p.minCircularity = True, 0.5
    p.filterByInertia, p.minInertiaRatio = True, 0.15
    p.filterByConvexity, p.minConvexity = True, 0.85
    p.minDistBetweenBlobs = 2.0
    return cv2.SimpleBlobDetector_create(p), img8


def find_grid(image: np.ndarray, target: DotGrid) -> np.ndarray | None:
    """findCirclesGrid's centres (rows·cols, 2) in its own order, or None."""
    import cv2
    detector, img8 = blob_detector(image, target.white_dots)
    for flags in (cv2.CALIB_CB_SYMMETRIC_GRID, cv2.CALIB_CB_SYMMETRIC_GRID | cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(img8, (target.cols, target.rows), flags=flags, blobDetector=detector)
        if found:
            return centres.reshape(-1, 2).astype(np.float64)
    return None


def regular(points: np.ndarray, rows: int, cols: int, tol: float = REGULARITY) -> bool:
    """Whether the grid is smooth: every second difference along rows and columns is below
    ``tol`` × the median spacing (perspective and lens distortion give a few %). It rejects
    the grids findCirclesGrid reports for partly visible targets with repeated points."""
    g = points.reshape(rows, cols, 2)
    spacing = np.median(np.concatenate([np.linalg.norm(np.diff(g, axis=a), axis=-1).ravel() for a in (0, 1)]))
    second = [np.linalg.norm(np.diff(g, 2, axis=a), axis=-1) for a in (0, 1)]
    return bool(spacing > 0 and max(float(d.max()) for d in second) < tol * spacing)


def grid_vectors(points: np.ndarray, rows: int, cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Local image vectors (N, 2) to the next column and the next row of each grid point
    (central differences inside, one-sided at the border)."""
    g = points.reshape(rows, cols, 2)
    return (np.gradient(g, axis=1).reshape(-1, 2), np.gradient(g, axis=0).reshape(-1, 2))


def centroid(image: np.ndarray, centre, e_col, e_row, white: bool, ring: float,
             window: float = WINDOW) -> tuple[np.ndarray, float] | None:
    """One grey-level centroid pass (see the module text): ``(centre, mass)`` with mass =
    Σ(I − b) in grey × px², or None if the window leaves the image.

    ``ring``: inner edge of the background ring, in grid spacings (outside every dot).
    """
    win = _window_pixels(image, centre, e_col, e_row, window)
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


# --- the dot model fit ------------------------------------------------------------------------------

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


def _window_pixels(image, centre, e_col, e_row, window):
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
        w = _window_pixels(image, points[k], e_col[k], e_row[k], window)
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


def _band_pixels(image, e: Ellipses, k: int, band: float, inner: bool = True):
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
            bp = _band_pixels(image, e, k, band[k]) if band[k] >= 1.0 else None
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


def centre_bound(image: np.ndarray, e: Ellipses, sigma: float, band=EDGE_BAND) -> np.ndarray:
    """The Cramér–Rao bound of each dot's centre (N, 2, 2 covariance, px²; NaN where lost) for
    white noise of σ = ``sigma`` (grey, full scale) on ``image``: (JᵀJ/σ²)⁻¹ of the model of
    :func:`fit_ellipses` at the fitted ``e`` over its band. No unbiased estimator of a dot's
    centre from these pixels does better."""
    n = len(e.centres)
    band = np.broadcast_to(np.asarray(band, float), (n,))
    out = np.full((n, 2, 2), np.nan)
    for k in np.flatnonzero(np.isfinite(e.centres[:, 0])):
        bp = _band_pixels(image, e, k, band[k])
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
            bp = _band_pixels(image, Ellipses(c[None], e.M[k][None], *(x[k:k + 1] for x in (e.background, e.contrast,
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


def grid_permutations(rows: int, cols: int) -> list[np.ndarray]:
    """Every re-numbering of a rows × cols grid that keeps its shape (rotations and mirrors)."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    out = [idx, idx[::-1], idx[:, ::-1], idx[::-1, ::-1]]
    if rows == cols:
        out += [g.T for g in out]
    return [g.ravel() for g in out]


def orient(points: np.ndarray, area: np.ndarray, target: DotGrid) -> np.ndarray | None:
    """The permutation that puts detected points into the target's order, or None if the
    markers do not say which.

    Mirror orderings are excluded by the handedness a camera sees the printed face with
    (columns × rows turning clockwise in the image); among the remaining turns, the one whose
    marker cells show the markers' area ratio wins (|log(area / median area) − log(expected
    ratio)| summed over the marker cells: below MARKER_TOLERANCE per marker, and less than half
    the next turn's). Without markers the turn whose column
    direction points most to the image's right is chosen (consistent between the cameras of a
    rig as long as the target is not rolled near ±45°/90°)."""
    rows, cols = target.rows, target.cols
    candidates = []
    for perm in grid_permutations(rows, cols):
        p = points[perm].reshape(rows, cols, 2)
        e_col = np.nanmean(p[:, 1:] - p[:, :-1], axis=(0, 1))
        e_row = np.nanmean(p[1:] - p[:-1], axis=(0, 1))
        if e_col[0] * e_row[1] - e_col[1] * e_row[0] > 0:
            candidates.append((perm, e_col))
    if not target.markers:
        return max(candidates, key=lambda c: c[1][0] / np.linalg.norm(c[1]))[0]
    expected = np.log((target.diameters() / target.dot_diameter) ** 2)
    cells = expected != 0                       # the marker cells: only they decide (noise elsewhere does not add up)
    ref = np.nanmedian(area)

    def misfit(perm):
        return np.nansum(np.abs(np.log(np.clip(area[perm][cells] / ref, 1e-6, None)) - expected[cells]))

    scores = sorted((misfit(perm), i) for i, (perm, _) in enumerate(candidates))
    best, i = scores[0]
    if best > MARKER_TOLERANCE * len(target.markers) or (len(scores) > 1 and scores[1][0] < 2 * best):
        return None
    return candidates[i][0]


def find_partial_grid(image: np.ndarray, target: DotGrid):
    """The dots in view when the grid is cut by the image border (or findCirclesGrid fails):
    ``(blobs, e_col, e_row)`` in the target's order, (N, 2) each, NaN where a dot was not found,
    or None. The markers anchor it: among the blobs of marker size, the three whose affine map
    from the marker cells predicts the most blobs of the cells around them (right-handed: the
    printed face) fix the labels; the grid then grows cell by cell, each predicted by an affine
    fit to the found cells within two cells and matched to the nearest blob within 0.3 of the
    local spacing. Needs the markers in view."""
    import itertools
    from scipy.spatial import cKDTree
    if not target.markers:
        return None
    detector, img8 = blob_detector(image, target.white_dots)
    kps = detector.detect(img8)
    if len(kps) < 6:
        return None
    P = np.array([k.pt for k in kps], np.float64)
    S = np.array([k.size for k in kps], np.float64)
    ratio = target.marker_diameter / target.dot_diameter
    cut = np.median(S) * (1 + ratio) / 2
    small = np.flatnonzero(S < cut if ratio < 1 else S > cut)
    if not 3 <= len(small) <= 12:
        return None
    rows, cols = target.rows, target.cols
    rc = np.stack(np.divmod(np.arange(rows * cols), cols), axis=1)            # (row, col) of every point
    design = np.c_[rc[:, 1], rc[:, 0], np.ones(len(rc))]                      # col, row, 1
    mk = np.array([r * cols + c for r, c in target.markers])
    near = np.flatnonzero(np.abs(rc[:, None, :] - rc[mk][None]).max(axis=2).min(axis=1) <= 2)
    tree = cKDTree(P)
    best = None
    for triple in itertools.permutations(small, 3):
        try:
            sol = np.linalg.solve(design[mk], P[list(triple)])                # (3, 2): e_col, e_row, origin
        except np.linalg.LinAlgError:
            continue
        e_col, e_row = sol[0], sol[1]
        spacing = min(np.linalg.norm(e_col), np.linalg.norm(e_row))
        if e_col[0] * e_row[1] - e_col[1] * e_row[0] <= 0 or spacing < 4:
            continue
        d, _ = tree.query(design[near] @ sol)
        score = int((d < 0.3 * spacing).sum())
        if best is None or score > best[0]:
            best = (score, sol)
    if best is None or best[0] < max(6, len(near) // 3):
        return None
    blobs = np.full((rows * cols, 2), np.nan)
    vec = np.full((rows * cols, 2, 2), np.nan)
    used = set()

    def local_affine(k):
        found = np.flatnonzero(~np.isnan(blobs[:, 0]))
        nb = found[np.abs(rc[found] - rc[k]).max(axis=1) <= 2]
        if len(nb) < 3 or np.linalg.matrix_rank(design[nb]) < 3:
            return None
        return np.linalg.lstsq(design[nb], blobs[nb], rcond=None)[0]

    def match(k, sol):
        e = np.linalg.norm(sol[:2], axis=1).min()
        d, j = tree.query(design[k] @ sol)
        if d < 0.3 * e and j not in used:
            blobs[k], vec[k] = P[j], sol[:2]
            used.add(j)
            return True
        return False

    for k in near:                                   # the cells around the markers, by the markers' map
        match(k, best[1])
    changed = True
    while changed:                                   # grow: each cell from the found cells around it
        changed = False
        todo = [k for k in range(rows * cols) if np.isnan(blobs[k, 0])]
        for k in sorted(todo, key=lambda k: np.abs(rc[k] - rc[mk]).max(axis=1).min()):
            sol = local_affine(k)
            if sol is not None and match(k, sol):
                changed = True
    for k in np.flatnonzero(~np.isnan(blobs[:, 0])):   # final local vectors from the grown grid
        sol = local_affine(k)
        if sol is not None:
            vec[k] = sol[:2]
    return blobs, vec[:, 0], vec[:, 1]


def inconsistent(points: np.ndarray, target: DotGrid) -> tuple[int, float] | None:
    """The dot farthest from where a homography fitted to its found neighbours (within two
    cells, itself left out) puts it, if farther than max(1 px, 0.05 × the local spacing):
    ``(index, distance px)``; None if every dot agrees. Lens distortion and perspective leave
    ≤ 0.7 px at 1624×1234; a wrongly matched dot is a spacing off."""
    import cv2
    rows, cols = target.rows, target.cols
    obj = target.points()[:, :2]
    rc = np.stack(np.divmod(np.arange(rows * cols), cols), axis=1)
    found = np.flatnonzero(~np.isnan(points[:, 0]))
    worst = None
    for k in found:
        nb = found[(np.abs(rc[found] - rc[k]).max(axis=1) <= 2) & (found != k)]
        if len(nb) < 6:
            continue
        H, _ = cv2.findHomography(obj[nb], points[nb], 0)
        if H is None:
            continue
        pred = cv2.perspectiveTransform(obj[k].reshape(1, 1, 2), H).ravel()
        d = float(np.linalg.norm(pred - points[k]))
        spacing = np.median(np.linalg.norm(points[nb] - points[k], axis=1) /
                            np.linalg.norm(obj[nb] - obj[k], axis=1)) * target.pitch
        if d > max(1.0, 0.05 * spacing) and (worst is None or d > worst[1]):
            worst = (int(k), d)
    return worst


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


# --- chessboards and ChArUco boards ------------------------------------------------------------------

def _gray8(image: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(image * 255), 0, 255).astype(np.uint8)


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
    found, corners = cv2.findChessboardCornersSB(_gray8(img), (C, R),
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
    corners, ids, _, _ = cv2.aruco.CharucoDetector(target.board()).detectBoard(_gray8(img))
    n = len(target.points())
    need = max(min_points or 4, 4)
    if ids is None or len(ids) < need:
        why = f"CharucoDetector found {0 if ids is None else len(ids)} corners, {need} needed"
        return (None, why) if explain else None
    pts = np.full((n, 2), np.nan)
    pts[ids.ravel()] = refine_charuco_corners(img, corners.reshape(-1, 2).astype(np.float64), target)
    d = Detection(points=pts, blobs=pts.copy(), ok=~np.isnan(pts[:, 0]))
    return (d, "") if explain else d


CHARUCO_MIN_GAP_PX = 8.0     # below this marker-to-corner gap OpenCV's corners are kept


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
