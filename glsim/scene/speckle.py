"""Reference speckle images: synthetic Boolean-model patterns, loading from file, statistics.

Grey levels are float32 in [0, 1] of full scale; images are (H, W) = (rows, cols) with
pixel centres at integer coordinates.
"""

import math
from dataclasses import dataclass

import numpy as np
from scipy import fft, ndimage, optimize

from glsim.errors import SceneError

_DOT_CHUNK = 20000  # dots rasterised per np.maximum.at call; bounds temporary memory


def _check_number(key, value, lo, hi, lo_open, hi_open, fix):
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SceneError(key, f"expected a number, got {value!r}", fix) from None
    too_low = x <= lo if lo_open else x < lo
    too_high = x >= hi if hi_open else x > hi
    if not math.isfinite(x) or too_low or too_high:
        interval = f"{'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
        raise SceneError(key, f"{value!r} is outside {interval}", fix)
    return x


def _check_shape(shape):
    try:
        h, w = (int(n) for n in shape)
        ok = (h, w) == tuple(shape) and h > 0 and w > 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise SceneError("speckle.shape", f"expected (rows, cols) of positive integers, got {shape!r}",
                         "give the image size in px, e.g. [1200, 1600]")
    return h, w


def _edge_profile(r, radius, edge_px):
    """Darkness in [0, 1] at distance r from a dot centre: smoothstep over edge_px, 0.5 at the radius.

    Nonzero only for r < radius + edge_px / 2 (strictly; also for the hard edge, edge_px = 0).
    """
    if edge_px == 0:
        return (r < radius).astype(np.float64)
    x = _edge_x(r, radius, edge_px)
    return x * x * (3.0 - 2.0 * x)


def _edge_x(r, radius, edge_px):
    return np.clip(0.5 - (r - radius) / edge_px, 0.0, 1.0)


def _edge_slope(r, radius, edge_px):
    """∂(:func:`_edge_profile`)/∂r per px: −smoothstep'(x)/edge_px on the edge, 0 elsewhere and for
    a hard edge."""
    if edge_px == 0:
        return np.zeros(np.shape(r))
    x = _edge_x(r, radius, edge_px)
    return -6.0 * x * (1.0 - x) / edge_px


@dataclass(frozen=True, eq=False)
class Dots:
    """A Boolean-model speckle as data: dot centres (n, 2) as (u, v) = (column, row) px,
    radii (n,) px, the smoothstep edge width px and the grey levels. Its exact grey value
    anywhere is :func:`evaluate`; :func:`generate` samples it at the pixel centres."""
    centres: np.ndarray
    radii: np.ndarray
    edge_px: float
    black: float
    white: float
    shape: tuple[int, int]

    @property
    def reach(self) -> float:
        """Largest distance (px) at which a dot still darkens."""
        return float(self.radii.max(initial=0.0)) + self.edge_px / 2


CELL_DIAMETERS = 16  # side of the pattern's lattice cells, in nominal dot diameters
BLACK, WHITE = 0.1, 0.9  # the generator's grey levels: dot cores, background


def pattern_args(dot_diameter, density, edge, diameter_spread=0.2, min_diameter=2.0, unit="px"):
    """The generator's arguments checked (SceneError naming the speckle key), as floats: the dot
    diameter at least ``min_diameter`` (2 px: smaller dots alias; 0: any positive size)."""
    fix = (f"give a dot diameter of at least {min_diameter:g} {unit} (smaller dots alias), e.g. 4" if min_diameter
           else "give a positive dot diameter")
    diameter = _check_number("speckle.dot_diameter_px", dot_diameter, min_diameter, math.inf,
                             not min_diameter, True, fix)
    density = _check_number("speckle.density", density, 0, 1, True, True,
                            "give the dark-area fraction strictly between 0 and 1, e.g. 0.5")
    edge = _check_number("speckle.edge_px", edge, 0, diameter, False, False,
                         "give an edge width between 0 (hard) and the dot diameter, e.g. 1.0")
    spread = _check_number("speckle.diameter_spread", diameter_spread, 0, 1, False, True,
                           "give the relative diameter spread in [0, 1), e.g. 0.2")
    return diameter, density, edge, spread


def _check_seed(seed):
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SceneError("speckle.seed", f"expected a non-negative integer, got {seed!r}",
                         "give an integer seed >= 0, e.g. 0")
    return int(seed)


def _grey_levels(black, white):
    black = _check_number("speckle.black", black, 0, 1, False, False, "give a grey level in [0, 1]")
    white = _check_number("speckle.white", white, 0, 1, False, False, "give a grey level in [0, 1]")
    if black >= white:
        raise SceneError("speckle.black", f"black ({black:g}) must be darker than white ({white:g})",
                         "give black < white, e.g. black = 0.1, white = 0.9")
    return black, white


def _zigzag(i: int) -> int:
    """A cell index as a non-negative integer (0, −1, 1, −2, … → 0, 1, 2, 3, …)."""
    return 2 * i if i >= 0 else -2 * i - 1


def pattern_reach(dot_diameter, edge, diameter_spread=0.2) -> float:
    """Largest distance from a dot's centre at which the dot still darkens (units of the diameter)."""
    return dot_diameter * (1 + diameter_spread) / 2 + edge / 2


def draw_pattern(lo, hi, dot_diameter, density=0.5, seed=0, edge=1.0, diameter_spread=0.2):
    """The dots of the Boolean-model pattern that reach the rectangle ``lo``…``hi`` (2-D, any
    length unit: mm on a specimen, px in an image): centres (n, 2) and radii (n,).

    The pattern is a property of the plane, not of the rectangle: the plane is cut into square
    cells of side ``CELL_DIAMETERS × dot_diameter`` anchored at its origin, and cell (i, j)
    holds a Poisson number of dots, uniform over the cell, drawn from a generator seeded by
    (``seed``, i, j) alone. A dot therefore sits at the same point whichever rectangle asks for
    it; a larger rectangle only adds dots. Diameters are uniform in ``dot_diameter × (1 ±
    diameter_spread)``; the intensity makes the expected dark-area fraction ``1 − exp(−λ ·
    mean dot area)`` equal to ``density``. ``edge``: the dots' smoothstep edge width, which only
    widens the margin of dots kept around the rectangle."""
    diameter, density, edge, spread = pattern_args(dot_diameter, density, edge, diameter_spread, 0, "")
    seed = _check_seed(seed)
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    reach = pattern_reach(diameter, edge, spread)
    mean_area = math.pi / 4 * diameter**2 * (1 + spread**2 / 3)  # E[d^2] of a uniform diameter
    cell = CELL_DIAMETERS * diameter
    per_cell = -math.log1p(-density) / mean_area * cell * cell   # expected dots per cell
    first = np.floor((lo - reach) / cell).astype(np.int64)
    last = np.floor((hi + reach) / cell).astype(np.int64)
    centres, radii = [np.zeros((0, 2))], [np.zeros(0)]
    for j in range(int(first[1]), int(last[1]) + 1):
        for i in range(int(first[0]), int(last[0]) + 1):
            rng = np.random.default_rng([seed, _zigzag(i), _zigzag(j)])
            n = rng.poisson(per_cell)
            xy = np.array([i, j], np.float64) * cell + rng.random((n, 2)) * cell
            r = diameter / 2 * rng.uniform(1 - spread, 1 + spread, n)
            keep = np.all((xy >= lo - reach) & (xy <= hi + reach), axis=1)
            centres.append(xy[keep])
            radii.append(r[keep])
    return np.concatenate(centres), np.concatenate(radii)


def draw_dots(shape, dot_diameter_px, density=0.5, seed=0, edge_px=1.0, black=BLACK, white=WHITE,
              diameter_spread=0.2) -> Dots:
    """The random dots of :func:`generate` (same arguments, same draws): :func:`draw_pattern`
    in the image's pixel coordinates (u, v) = (column, row), its lattice anchored at the centre
    of pixel (0, 0), so a larger image holds the smaller one's dots at the same pixels."""
    h, w = _check_shape(shape)
    diameter, density, edge_px, spread = pattern_args(dot_diameter_px, density, edge_px, diameter_spread, 2, "px")
    black, white = _grey_levels(black, white)
    centres, radii = draw_pattern((-0.5, -0.5), (w - 0.5, h - 0.5), diameter, density, seed, edge_px, spread)
    return Dots(centres, radii, edge_px, black, white, (h, w))


def generate(shape, dot_diameter_px, density=0.5, seed=0, edge_px=1.0, black=BLACK, white=WHITE,
             diameter_spread=0.2):
    """Random-disc (Boolean model) speckle pattern: dark dots on a white background.

    Dot centres are a Poisson process over the image and a margin around it, drawn cell by
    cell (:func:`draw_pattern`); diameters are uniform in ``dot_diameter_px * (1 +-
    diameter_spread)``. The dot count makes the expected dark-area fraction ``1 - exp(-lambda *
    mean dot area)`` equal to ``density``. Each dot's edge is a smoothstep ramp of full width
    ``edge_px`` px (0 = hard edge) centred on its radius; overlapping dots combine by maximum
    darkness. Grey levels go from ``white`` (background) to ``black`` (dot cores).

    Returns float32 (H, W) in [0, 1]; the same arguments give bit-identical output.
    """
    return rasterize(draw_dots(shape, dot_diameter_px, density, seed, edge_px, black, white, diameter_spread))


def rasterize(dots: Dots) -> np.ndarray:
    """``dots`` sampled at every pixel centre of their image, float32 (H, W)."""
    h, w = dots.shape
    reach = dots.reach
    # A px within reach of a centre is within reach + 0.5 of the px nearest that centre.
    half = max(math.ceil(reach + 0.5) - 1, 0)
    offsets = np.arange(-half, half + 1)
    pad = half + math.ceil(reach) + 1  # canvas margin: every window fits without bounds checks
    canvas = np.zeros((h + 2 * pad, w + 2 * pad))
    for start in range(0, len(dots.radii), _DOT_CHUNK):
        c = dots.centres[start:start + _DOT_CHUNK, ::-1]  # (row, col)
        r = dots.radii[start:start + _DOT_CHUNK]
        near = np.rint(c).astype(np.intp)
        rows = near[:, 0, None, None] + offsets[None, :, None]
        cols = near[:, 1, None, None] + offsets[None, None, :]
        dist = np.hypot(rows - c[:, 0, None, None], cols - c[:, 1, None, None])
        dark = _edge_profile(dist, r[:, None, None], dots.edge_px)
        np.maximum.at(canvas, (rows + pad, cols + pad), dark)
    darkness = canvas[pad:pad + h, pad:pad + w]
    return (dots.white - (dots.white - dots.black) * darkness).astype(np.float32)


@dataclass(frozen=True, eq=False)
class DotGrid:
    """Uniform grid over the dots for lookup: cell size ≥ their reach, so a point's dots lie
    in its own and the 8 neighbouring cells. ``start``/``count`` (ny·nx) index ``order``."""
    origin: tuple[float, float]
    cell: float
    dims: tuple[int, int]    # nx, ny
    start: np.ndarray
    count: np.ndarray
    order: np.ndarray


def dot_grid(dots: Dots) -> DotGrid:
    """Bin the dots' centres into cells of size max(reach, 1) px (CSR layout), rounded up to a
    float32 value: the shaders (procedural.glsl) take it as a float uniform, and a cell corner
    k·cell must be the same there as here, where the dots' offsets from their corners are made."""
    reach = max(dots.reach, 1.0)
    cell = float(np.float32(reach))
    if cell < reach:
        cell = float(np.nextafter(np.float32(reach), np.float32(np.inf)))
    origin = dots.centres.min(axis=0) if len(dots.radii) else np.zeros(2)
    ij = np.floor((dots.centres - origin) / cell).astype(np.int64)
    nx, ny = (ij.max(axis=0) + 1) if len(dots.radii) else (1, 1)
    flat = ij[:, 1] * nx + ij[:, 0]
    order = np.argsort(flat, kind="stable")
    count = np.bincount(flat, minlength=nx * ny)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    return DotGrid((float(origin[0]), float(origin[1])), float(cell), (int(nx), int(ny)),
                   start, count, order)


def evaluate(dots: Dots, uv, grid: DotGrid | None = None) -> np.ndarray:
    """Exact grey level of the Boolean-model speckle at reference coordinates uv (..., 2) px
    (u = column, v = row): no interpolation. float64."""
    uv = np.asarray(uv, dtype=np.float64)
    darkness, _ = _darkness(dots, uv.reshape(-1, 2), grid or dot_grid(dots), gradient=False)
    return (dots.white - (dots.white - dots.black) * darkness).reshape(uv.shape[:-1])


def gradient(dots: Dots, uv, grid: DotGrid | None = None) -> np.ndarray:
    """∂(:func:`evaluate`)/∂(u, v) (..., 2) grey per px: the darkest dot's smoothstep edge
    (where dots overlap the darkness is their maximum, whose derivative is its dot's); 0 inside
    and outside the edges. A hard edge (edge_px = 0) has none."""
    uv = np.asarray(uv, dtype=np.float64)
    _, grad = _darkness(dots, uv.reshape(-1, 2), grid or dot_grid(dots), gradient=True)
    return (-(dots.white - dots.black) * grad).reshape(uv.shape)


def _darkness(dots: Dots, uv: np.ndarray, grid: DotGrid, gradient: bool):
    """The darkness (n,) in [0, 1] at uv (n, 2) — the maximum of the dots' edge profiles — and,
    with ``gradient``, its derivative (n, 2) per px (the maximising dot's), else None."""
    darkness = np.zeros(len(uv))
    grad = np.zeros((len(uv), 2)) if gradient else None
    cell = np.floor((uv - grid.origin) / grid.cell).astype(np.int64)
    nx, ny = grid.dims
    for dj in (-1, 0, 1):
        for di in (-1, 0, 1):
            ci, cj = cell[:, 0] + di, cell[:, 1] + dj
            inside = (ci >= 0) & (ci < nx) & (cj >= 0) & (cj < ny)
            k = np.where(inside, cj * nx + ci, 0)
            n = np.where(inside, grid.count[k], 0)
            for m in range(int(n.max(initial=0))):
                has = n > m
                idx = grid.order[grid.start[k[has]] + m]
                offset = uv[has] - dots.centres[idx]
                d = np.hypot(*offset.T)
                profile = _edge_profile(d, dots.radii[idx], dots.edge_px)
                if gradient:   # where this dot is the darkest so far, its slope along (uv − c)/d
                    slope = np.where(d > 0, _edge_slope(d, dots.radii[idx], dots.edge_px) / np.where(d > 0, d, 1.0), 0.0)
                    darker = profile > darkness[has]
                    rows = np.flatnonzero(has)[darker]
                    grad[rows] = slope[darker, None] * offset[darker]
                darkness[has] = np.maximum(darkness[has], profile)
    return darkness, grad



def autocorrelation(img, max_lag):
    """Normalised autocorrelation of the mean-subtracted image at lags (dy, dx) in [-max_lag, max_lag]^2.

    Each lag is averaged over its overlapping pixel pairs only (no wrap-around).
    Returns (2 max_lag + 1, 2 max_lag + 1) with lag 0 = 1 at the centre; NaN for a flat image.
    """
    x = np.asarray(img, dtype=np.float64)
    x = x - x.mean()
    h, w = x.shape
    # Zero padding by max_lag keeps the wanted lags free of wrap-around.
    size = (fft.next_fast_len(h + max_lag, real=True), fft.next_fast_len(w + max_lag, real=True))
    spec = fft.rfft2(x, s=size)
    full = fft.irfft2(spec * np.conj(spec), s=size)
    lags = np.arange(-max_lag, max_lag + 1)
    local = full[np.ix_(lags % size[0], lags % size[1])]
    pairs = (h - np.abs(lags))[:, None] * (w - np.abs(lags))[None, :]
    cov = local / pairs
    c0 = cov[max_lag, max_lag]
    return cov / c0 if c0 > 0 else np.full_like(cov, np.nan)


def _hwhm(acf):
    """Lag (px) where the mean of the four axis profiles of ``acf`` first falls to one half."""
    m = acf.shape[0] // 2
    profile = (acf[m, m:] + acf[m, m::-1] + acf[m:, m] + acf[m::-1, m]) / 4
    below = np.nonzero(profile < 0.5)[0]
    if below.size == 0:
        return float("nan")
    k = below[0]
    return float(k - 1 + (profile[k - 1] - 0.5) / (profile[k - 1] - profile[k]))


def _disc_covariogram(x):
    """Overlap area of two unit-diameter discs at centre distance x, over the disc area."""
    x = np.minimum(x, 1.0)
    return 2 / np.pi * (np.arccos(x) - x * np.sqrt(1 - x * x))


def _boolean_dot_diameter(dark, max_lag):
    """Dot diameter (px) of a Boolean disc model fitted to the dark phase's autocorrelation.

    For discs of diameter D at light fraction q, the light (or dark) indicator has
    autocorrelation q (q^(-g(r / D)) - 1) / (1 - q), g the normalised disc covariogram;
    unlike component sizes this does not grow where dots overlap. Point sampling at
    pixel centres leaves the covariance unbiased.
    """
    q = 1.0 - dark.mean()
    if not 0 < q < 1:
        return float("nan")
    acf = autocorrelation(dark, max_lag)
    r_half = _hwhm(acf)
    if not math.isfinite(r_half):
        return float("nan")
    # The model is zero beyond r = D, about 3 HWHM at q = 0.5; fit a little past that.
    m = min(max_lag, math.ceil(5 * r_half) + 2)
    dy, dx = np.mgrid[-m:m + 1, -m:m + 1]
    r = np.hypot(dy, dx)
    measured = acf[max_lag - m:max_lag + m + 1, max_lag - m:max_lag + m + 1]

    def misfit(d):
        model = q * (q ** -_disc_covariogram(r / d) - 1) / (1 - q)
        return float(np.sum((measured - model) ** 2))

    return float(optimize.minimize_scalar(misfit, bounds=(0.5, 4 * m), method="bounded").x)


def _component_diameters(dark):
    """Equivalent diameters sqrt(4 area / pi) (px) of the 4-connected dark components not touching the border."""
    labels, n = ndimage.label(dark)
    areas = np.bincount(labels.ravel(), minlength=n + 1)
    keep = np.ones(n + 1, bool)
    keep[0] = False
    keep[np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])] = False
    return np.sqrt(4 * areas[keep] / np.pi)


def speckle_stats(img, threshold=None):
    """What a DIC user checks in a speckle pattern, as a dict.

    The dark phase is the pixels below ``threshold`` (default: mid grey, halfway between
    the 1st and 99th grey-level percentiles).

    - ``speckle_diameter_px``: median equivalent diameter of the dark speckles (connected
      components not touching the border); overlapping dots merge, so at densities
      around 0.5 this exceeds the dot diameter, and it is meaningless above about 0.65
      where the dark phase percolates
    - ``n_speckles``: number of those speckles
    - ``dot_diameter_px``: dot diameter of a random-disc (Boolean) model fitted to the
      dark phase's autocorrelation; recovers ``generate``'s ``dot_diameter_px`` at any density
    - ``covered_fraction``: dark-phase fraction of the pixels
    - ``grey_mean``, ``grey_std``: grey-level mean and standard deviation
    - ``autocorr_radius_px``: half width at half maximum (px) of the grey-level autocorrelation
    """
    x = np.asarray(img, dtype=np.float64)
    if x.ndim != 2 or min(x.shape) < 8:
        raise ValueError(f"expected a 2-D (H, W) image of at least 8x8 px, got shape {x.shape}")
    if threshold is None:
        lo, hi = np.percentile(x, [1, 99])
        threshold = (lo + hi) / 2
    dark = x < threshold
    max_lag = min(x.shape) // 4
    diameters = _component_diameters(dark)
    return {
        "speckle_diameter_px": float(np.median(diameters)) if diameters.size else float("nan"),
        "n_speckles": int(diameters.size),
        "dot_diameter_px": _boolean_dot_diameter(dark, max_lag),
        "covered_fraction": float(dark.mean()),
        "grey_mean": float(x.mean()),
        "grey_std": float(x.std()),
        "autocorr_radius_px": _hwhm(autocorrelation(x, max_lag)),
    }
