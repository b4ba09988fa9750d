"""Random displacement fields on any specimen (``[specimen.field]``): the training sets of learned
DIC need many smooth, seeded fields on one specimen. One :class:`Field` sums its components in the
specimen's own frame (mm, before ``specimen.pose``), evaluated in float64 at every node — the
mid-side and centre nodes of quadratic elements too, so the FE field is the interpolant of the
nodal values:

- ``random``: a smooth Gaussian random field per component u, v, w, covariance
  std²·exp(−r²/2ℓ²) (r: the 3-D distance of two points), as a sum of ``features`` random cosines
  (random Fourier features: ω ~ N(0, I/ℓ²), phase ~ U[0, 2π)), which works on any node set;
- ``affine``: u = t + G·(X − origin), G and t fixed or drawn within bounds;
- ``bumps`` (fixed) and ``random_bumps`` (drawn): Gaussian bumps a·exp(−|X − c|²/2r²);
- ``cracks``: a displacement jump along a line segment; the mesh is split along the element
  edges nearest the segment (:func:`split_along`) and the opening applied to the left side.

``max_displacement_px`` scales the summed field so that its largest in-plane |(u, v)| at the
nodes, in camera-0 pixels (fx/Z at the node), equals it. Each component draws from its own
random stream, seeded from ``seed`` and the component's name (as a library's [vary] keys do), so
changing one component's parameters leaves the others' draws as they were.
"""
from __future__ import annotations

import dataclasses
import math
import zlib
from dataclasses import dataclass

import numpy as np

from glsim.errors import SceneError, check
from glsim.limits import MAX_COORDINATE_MM
from glsim.scene.camera import Camera
from glsim.scene.mesh import Mesh

Vec3 = tuple[float, float, float]

MAX_FEATURES = 4096          # cosines of one random component
MAX_BUMPS = 10_000           # fixed plus drawn bumps
MAX_CRACKS = 64
MAX_FIELD_WORK = 1 << 32     # nodes × features × 3: the random field's cosines (about a minute at most)
MAX_PX = 1e4                 # max_displacement_px
MAX_STRAIN = 10.0            # |entries| of an affine gradient (a stretch of 1000 %)
MAX_SEED = 2 ** 63           # seeds are TOML integers


def _number(value, key: str, what: str) -> float:
    check(isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool), key,
          f"expected a number, got {value!r}", f"give {what}")
    check(math.isfinite(value), key, f"must be finite, got {value}", f"give {what}")
    return float(value)


def _length(value, key: str, what: str, positive: bool = False) -> float:
    v = _number(value, key, what)
    check(abs(v) <= MAX_COORDINATE_MM, key, f"{v:g} mm lies beyond glsim's limit of ±{MAX_COORDINATE_MM:g} mm",
          f"give {what}")
    check(not positive or v > 0, key, f"must be > 0, got {v:g}", f"give {what}")
    return v


def _lengths(value, key: str, what: str, sizes=(3,), positive: bool = False) -> tuple[float, ...]:
    check(isinstance(value, (list, tuple)) and len(value) in sizes, key,
          f"expected a list of {' or '.join(map(str, sizes))} numbers, got {value!r}", f"give {what}")
    return tuple(_length(v, f"{key}[{i}]", what, positive) for i, v in enumerate(value))


def _range(value, key: str, what: str, low: float, high: float, integer: bool = False):
    """A number, or [lo, hi] with lo ≤ hi (drawn uniformly), each within [low, high]."""
    kind = "an integer" if integer else "a number"
    if isinstance(value, (list, tuple)):
        check(len(value) == 2, key, f"expected {kind} or [low, high], got {value!r}", f"give {what}")
        pair = tuple(_range(v, f"{key}[{i}]", what, low, high, integer) for i, v in enumerate(value))
        check(pair[0] <= pair[1], key, f"low {pair[0]:g} is above high {pair[1]:g}", "give [low, high]")
        return pair
    if integer:
        check(isinstance(value, (int, np.integer)) and not isinstance(value, bool), key,
              f"expected {kind} or [low, high], got {value!r}", f"give {what}")
    v = _number(value, key, what)
    check(low <= v <= high, key, f"{v:g} lies outside [{low:g}, {high:g}]", f"give {what}")
    return int(v) if integer else v


def _bounds(value) -> tuple:
    return value if isinstance(value, tuple) else (value, value)


@dataclass(frozen=True)
class RandomField:
    """A stationary Gaussian random field per component: ``std`` = [σu, σv, σw] (mm, the standard
    deviation of each component at every point), ``correlation_length`` ℓ (mm, the covariance is
    σ²·exp(−r²/2ℓ²)), ``features``: the number of random cosines summed (more: closer to Gaussian;
    the covariance is exact in the mean over seeds for any number)."""
    correlation_length: float
    std: Vec3 = (1.0, 1.0, 0.0)
    features: int = 512

    def __post_init__(self):
        key = "specimen.field.random"
        _length(self.correlation_length, f"{key}.correlation_length", "the correlation length ℓ in mm, > 0", True)
        std = _lengths(self.std, f"{key}.std", "[σu, σv, σw] in mm, each ≥ 0")
        check(min(std) >= 0, f"{key}.std", f"must be ≥ 0, got {list(std)}", "give [σu, σv, σw] in mm, each ≥ 0")
        _range(self.features, f"{key}.features", f"a count of cosines in 1…{MAX_FEATURES}, e.g. 512", 1,
               MAX_FEATURES, integer=True)
        object.__setattr__(self, "std", std)


@dataclass(frozen=True)
class Affine:
    """u = translation + G·(X − origin). G is ``gradient`` (2×2 in-plane [[∂u/∂X, ∂u/∂Y], [∂v/∂X,
    ∂v/∂Y]] or 3×3), or drawn: each in-plane entry uniformly in [−gradient_max, gradient_max].
    The translation is ``translation`` (mm), or drawn: each component uniformly in
    [−translation_max, translation_max]. ``origin``: [X, Y] or [X, Y, Z] (mm), default the
    centre of the nodes' bounding box."""
    gradient: tuple = ()
    gradient_max: float = 0.0
    translation: Vec3 = (0.0, 0.0, 0.0)
    translation_max: Vec3 = (0.0, 0.0, 0.0)
    origin: tuple = ()

    def __post_init__(self):
        key = "specimen.field.affine"
        g = self.gradient
        check(isinstance(g, (list, tuple)) and (len(g) == 0 or len(g) in (2, 3) and all(
              isinstance(row, (list, tuple)) and len(row) == len(g) for row in g)), f"{key}.gradient",
              f"expected a 2×2 or 3×3 matrix, got {g!r}", "give [[dudX, dudY], [dvdX, dvdY]] (or 3×3)")
        rows = tuple(tuple(_number(v, f"{key}.gradient[{i}][{j}]", "a displacement gradient entry")
                           for j, v in enumerate(row)) for i, row in enumerate(g))
        check(all(abs(v) <= MAX_STRAIN for row in rows for v in row), f"{key}.gradient",
              f"has an entry beyond ±{MAX_STRAIN:g}", "give the displacement gradient (dimensionless, e.g. 0.01)")
        gmax = _range(self.gradient_max, f"{key}.gradient_max", f"a bound in [0, {MAX_STRAIN:g}], e.g. 0.01",
                      0.0, MAX_STRAIN)
        check(not (rows and gmax), f"{key}.gradient_max", "gradient is given too",
              "give a fixed gradient or gradient_max to draw one, not both")
        t = _lengths(self.translation, f"{key}.translation", "[tu, tv, tw] in mm")
        tmax = _lengths(self.translation_max, f"{key}.translation_max", "[tu, tv, tw] bounds in mm, each ≥ 0")
        check(min(tmax) >= 0, f"{key}.translation_max", f"must be ≥ 0, got {list(tmax)}", "give bounds in mm")
        check(not (any(t) and any(tmax)), f"{key}.translation_max", "translation is given too",
              "give a fixed translation or translation_max to draw one, not both")
        origin = _lengths(self.origin, f"{key}.origin", "[X, Y] or [X, Y, Z] in mm", (0, 2, 3))
        for k, v in (("gradient", rows), ("gradient_max", float(gmax)), ("translation", t),
                     ("translation_max", tmax), ("origin", origin)):
            object.__setattr__(self, k, v)


@dataclass(frozen=True)
class Bump:
    """A Gaussian bump amplitude·exp(−|X − centre|²/2·radius²): ``centre`` [X, Y] (distance in the
    XY plane) or [X, Y, Z] (3-D distance), mm; ``radius`` its standard deviation (mm);
    ``amplitude`` [au, av, aw] (mm)."""
    centre: tuple
    radius: float
    amplitude: Vec3

    def __post_init__(self):
        object.__setattr__(self, "centre", _lengths(self.centre, "centre", "[X, Y] or [X, Y, Z] in mm", (2, 3)))
        _length(self.radius, "radius", "the bump's radius (σ) in mm, > 0", True)
        object.__setattr__(self, "amplitude", _lengths(self.amplitude, "amplitude", "[au, av, aw] in mm"))


@dataclass(frozen=True)
class RandomBumps:
    """``count`` bumps (or [low, high]: drawn, both included), each with its centre [X, Y] drawn
    uniformly over the nodes' XY bounding box, its ``radius`` (mm, or [low, high]) drawn uniformly
    and each amplitude component uniformly in ±``amplitude`` (mm)."""
    amplitude: Vec3
    count: int | tuple = 1
    radius: float | tuple = 5.0

    def __post_init__(self):
        key = "specimen.field.random_bumps"
        count = _range(self.count, f"{key}.count", f"a count in 0…{MAX_BUMPS}, or [low, high]", 0, MAX_BUMPS, True)
        radius = _range(self.radius, f"{key}.radius", "the radius in mm (> 0), or [low, high]", 0.0,
                        MAX_COORDINATE_MM)
        check(min(_bounds(radius)) > 0, f"{key}.radius", f"must be > 0, got {radius}", "give the radius in mm")
        amp = _lengths(self.amplitude, f"{key}.amplitude", "[au, av, aw] bounds in mm, each ≥ 0")
        check(min(amp) >= 0 and max(amp) > 0, f"{key}.amplitude", f"must be ≥ 0 and not all 0, got {list(amp)}",
              "give bounds [au, av, aw] in mm")
        for k, v in (("count", count), ("radius", radius), ("amplitude", amp)):
            object.__setattr__(self, k, v)


@dataclass(frozen=True)
class Crack:
    """A displacement jump along the segment ``start`` → ``end`` ([X, Y], mm, in the specimen's
    plane). The side to the left of start → end (seen from +Z) moves by opening·p(s)·exp(−d²/2h²)
    (d: distance from the segment, h = ``decay``, default the crack's length), the right side not:
    p = 1 at an end on the specimen's boundary, → 0 as √r at a tip inside it (r: distance from
    the tip)."""
    start: tuple
    end: tuple
    opening: Vec3
    decay: float = 0.0

    def __post_init__(self):
        start = _lengths(self.start, "start", "[X, Y] in mm", (2,))
        end = _lengths(self.end, "end", "[X, Y] in mm", (2,))
        check(start != end, "end", f"equals start {list(start)}", "give a segment of non-zero length")
        opening = _lengths(self.opening, "opening", "the jump [du, dv, dw] in mm")
        decay = _length(self.decay, "decay", "the decay length in mm (0: the crack's length)")
        check(decay >= 0, "decay", f"must be ≥ 0, got {decay:g}", "give a length in mm, or 0")
        for k, v in (("start", start), ("end", end), ("opening", opening), ("decay", decay)):
            object.__setattr__(self, k, v)


@dataclass(frozen=True)
class Field:
    """``[specimen.field]``: one displacement field (the sum of the components given) added to
    every load step after 0, or, where the specimen has none, as load step 1. ``seed`` seeds every
    draw; ``max_displacement_px`` (a number, or [low, high] drawn uniformly; 0: off) scales the
    summed field so that its largest |(u, v)| at the nodes, in camera-0 px (fx/Z), equals it."""
    seed: int = 0
    random: RandomField | None = None
    affine: Affine | None = None
    bumps: tuple[Bump, ...] = ()
    random_bumps: RandomBumps | None = None
    cracks: tuple[Crack, ...] = ()
    max_displacement_px: float | tuple = 0.0

    def __post_init__(self):
        key = "specimen.field"
        check(isinstance(self.seed, (int, np.integer)) and not isinstance(self.seed, bool)
              and 0 <= self.seed < MAX_SEED, f"{key}.seed", f"must be an integer in [0, 2⁶³), got {self.seed!r}",
              "give a seed, e.g. 0")
        check(any((self.random, self.affine, self.bumps, self.random_bumps, self.cracks)), key,
              "gives no component", "add random, affine, bumps, random_bumps or cracks, or remove [specimen.field]")
        for name, cls in (("bumps", Bump), ("cracks", Crack)):
            items = getattr(self, name)
            check(isinstance(items, (list, tuple)) and all(isinstance(b, cls) for b in items), f"{key}.{name}",
                  f"expected a list of tables, got {items!r}", f"write [[{key}.{name}]] tables")
            object.__setattr__(self, name, tuple(items))
        rb = self.random_bumps
        refuse = len(self.bumps) + (max(_bounds(rb.count)) if rb else 0) > MAX_BUMPS
        check(not refuse, f"{key}.bumps", f"more than {MAX_BUMPS} bumps in all", "give fewer bumps")
        check(len(self.cracks) <= MAX_CRACKS, f"{key}.cracks", f"{len(self.cracks)} cracks, more than {MAX_CRACKS}",
              "give fewer cracks")
        px = _range(self.max_displacement_px, f"{key}.max_displacement_px",
                    f"the largest in-plane displacement in camera-0 px, in [0, {MAX_PX:g}] (or [low, high])",
                    0.0, MAX_PX)
        check(min(_bounds(px)) > 0 or max(_bounds(px)) == 0, f"{key}.max_displacement_px",
              f"the range {px} includes 0", "give a range of positive values, or 0 for no scaling")
        object.__setattr__(self, "seed", int(self.seed))
        object.__setattr__(self, "max_displacement_px", px)


# --- draws --------------------------------------------------------------------------------

def stream(seed: int, name: str) -> np.random.Generator:
    """The random stream of component ``name``: its own, so other components' settings do not move
    its draws (the library's per-key streams alike)."""
    return np.random.default_rng(np.random.SeedSequence([seed, zlib.crc32(name.encode())]))


def random_displacement(rf: RandomField, seed: int, X: np.ndarray) -> np.ndarray:
    """The random field (N, 3) mm at the points X (N, 3): per component c, σc·√(2/M)·Σₖ cos(ωₖ·X + bₖ)
    with ωₖ ~ N(0, I/ℓ²) and bₖ ~ U[0, 2π) from the stream ``random.u`` (``.v``, ``.w``). Its mean
    over seeds is 0 and its covariance σc²·exp(−|X − Y|²/2ℓ²), exactly for any M (Bochner); for
    finite M the values are a sum of M cosines (kurtosis 3 − 1.5/M, Gaussian as M grows)."""
    X = np.asarray(X, dtype=np.float64)
    out = np.zeros((len(X), 3))
    M = rf.features
    rows = max(1, (1 << 22) // M)          # bound the (rows, M) phase block to 32 MiB
    for c, name in enumerate("uvw"):
        rng = stream(seed, f"random.{name}")
        omega = rng.standard_normal((M, 3)) / rf.correlation_length
        phase = rng.uniform(0.0, 2 * np.pi, M)
        if rf.std[c] == 0:
            continue
        for i in range(0, len(X), rows):   # elementwise products and sums: no BLAS, the same bits everywhere
            x = X[i:i + rows]
            arg = x[:, 0:1] * omega[:, 0]
            arg += x[:, 1:2] * omega[:, 1]
            arg += x[:, 2:3] * omega[:, 2]
            arg += phase
            out[i:i + rows, c] = np.cos(arg, out=arg).sum(axis=1)
        out[:, c] *= rf.std[c] * math.sqrt(2.0 / M)
    return out


def box(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return X.min(axis=0), X.max(axis=0)


def affine_displacement(a: Affine, seed: int, X: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """t + G·(X − origin) (N, 3), drawn parts from the stream ``affine`` (four in-plane gradient
    entries then three translation components, each U[−1, 1) times its bound, always drawn)."""
    rng = stream(seed, "affine")
    g_draw, t_draw = rng.uniform(-1.0, 1.0, 4), rng.uniform(-1.0, 1.0, 3)
    G = np.zeros((3, 3))
    if a.gradient:
        n = len(a.gradient)
        G[:n, :n] = a.gradient
    else:
        G[:2, :2] = a.gradient_max * g_draw.reshape(2, 2)
    t = np.asarray(a.translation) if any(a.translation) else np.asarray(a.translation_max) * t_draw
    origin = 0.5 * (lo + hi)
    origin[:len(a.origin)] = a.origin
    return t + (X - origin) @ G.T


def drawn_bumps(rb: RandomBumps, seed: int, lo: np.ndarray, hi: np.ndarray) -> tuple[Bump, ...]:
    """The bumps of ``random_bumps`` from the stream ``bumps``: the count, then per bump its centre
    (2), radius and amplitude (3), in that order (so bump k does not depend on the count)."""
    rng = stream(seed, "bumps")
    c_lo, c_hi = _bounds(rb.count)
    count = int(rng.integers(c_lo, c_hi + 1))
    r_lo, r_hi = _bounds(rb.radius)
    out = []
    for _ in range(count):
        centre = lo[:2] + rng.uniform(0.0, 1.0, 2) * (hi[:2] - lo[:2])
        radius = r_lo + rng.uniform(0.0, 1.0) * (r_hi - r_lo)
        amp = rng.uniform(-1.0, 1.0, 3) * np.asarray(rb.amplitude)
        out.append(Bump(tuple(centre.tolist()), float(radius), tuple(amp.tolist())))
    return tuple(out)


def bump_displacement(bumps, X: np.ndarray) -> np.ndarray:
    out = np.zeros((len(X), 3))
    for b in bumps:
        c = np.asarray(b.centre)
        r2 = ((X[:, :len(c)] - c) ** 2).sum(axis=1)
        out += np.exp(-r2 / (2 * b.radius ** 2))[:, None] * np.asarray(b.amplitude)
    return out


def drawn_scale(field: Field) -> float:
    """The target of ``max_displacement_px``: the number, or U[low, high) from the stream
    ``max_displacement_px`` (0: no scaling)."""
    lo, hi = _bounds(field.max_displacement_px)
    draw = stream(field.seed, "max_displacement_px").uniform(0.0, 1.0)
    return float(lo + draw * (hi - lo)) if hi > lo else float(lo)


# --- cracks -------------------------------------------------------------------------------

def _segment(P: np.ndarray, a: np.ndarray, b: np.ndarray):
    """For XY points P (N, 2): the arc length s ∈ [0, L] of the nearest segment point, the distance
    d to it, and the side (cross product of b − a and P − a)."""
    ab = b - a
    L = float(np.hypot(*ab))
    s = np.clip(((P - a) @ ab) / L, 0.0, L)
    foot = a + s[:, None] * (ab / L)
    d = np.hypot(*(P - foot).T)
    cross = ab[0] * (P[:, 1] - a[1]) - ab[1] * (P[:, 0] - a[0])
    return s, d, cross, L


def _edges(quads: np.ndarray):
    """Element corner edges: (E, 2) sorted node pairs, and per row of ``quads`` × 4 the edge index
    (−1 for a collapsed edge of a triangle)."""
    pairs = np.stack([quads, np.roll(quads, -1, axis=1)], -1).reshape(-1, 2)
    real = pairs[:, 0] != pairs[:, 1]
    uniq, inv = np.unique(np.sort(pairs[real], axis=1), axis=0, return_inverse=True)
    index = np.full(len(pairs), -1)
    index[real] = inv.ravel()
    return uniq, index.reshape(-1, 4)


@dataclass(frozen=True)
class Split:
    """A mesh split along a crack: the mesh, and per node its side of the crack (+1 left, −1 right)
    and whether each end of the crack is a tip inside the specimen."""
    mesh: Mesh
    side: np.ndarray
    source: np.ndarray        # per node of ``mesh``: the node of the unsplit mesh it copies
    tips: tuple[bool, bool]


def _crack_path(mesh: Mesh, crack: Crack, key: str, edges: np.ndarray) -> list[int]:
    """Node indices of the edge path nearest the segment: Dijkstra over the element edges, each
    weighted by ∫ distance-to-segment along it (plus a tie-breaking 1e-6 of its length), from the
    node nearest ``start`` to the node nearest ``end`` (in the XY plane)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    xy = mesh.nodes[:, :2]
    a, b = np.asarray(crack.start), np.asarray(crack.end)
    lengths = np.hypot(*(xy[edges[:, 0]] - xy[edges[:, 1]]).T)
    longest = float(lengths.max())
    ends = []
    for name, p in (("start", a), ("end", b)):
        dist = np.hypot(*(xy - p).T)
        n = int(np.argmin(dist))
        check(dist[n] <= longest, f"{key}.{name}", f"{list(getattr(crack, name))} lies {dist[n]:.4g} mm from the "
              f"nearest node, farther than the longest element edge ({longest:.4g} mm): outside the specimen",
              "give the crack's ends on or inside the specimen (in its own frame, mm; an edge crack starts on "
              "its boundary)")
        ends.append(n)
    check(ends[0] != ends[1], key, f"start and end snap to the same node (label {int(mesh.node_labels[ends[0]])})",
          "give a crack longer than the elements there")
    d = [_segment(xy[edges[:, k]], a, b)[1] for k in (0, 1)]
    dm = _segment(0.5 * (xy[edges[:, 0]] + xy[edges[:, 1]]), a, b)[1]
    cost = lengths * ((d[0] + 4 * dm + d[1]) / 6 + 1e-6 * longest)    # Simpson's ∫ d ds, ties to the shortest
    n = mesh.n_nodes
    graph = coo_matrix((cost, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    dist, pred = dijkstra(graph, directed=False, indices=ends[0], return_predecessors=True)
    check(np.isfinite(dist[ends[1]]), key, "its ends lie on parts of the mesh that share no edge",
          "give a crack within one connected part of the specimen")
    path = [ends[1]]
    while path[-1] != ends[0]:
        path.append(int(pred[path[-1]]))
    return path[::-1]


def split_along(mesh: Mesh, crack: Crack, key: str = "specimen.field.cracks[0]") -> Split:
    """Split ``mesh`` (specimen frame, mm) along ``crack``: the path of element edges nearest the
    segment (:func:`_crack_path`); each path node where the elements around it fall apart into a
    left and a right group when the path edges are cut (every path node but a tip inside the
    specimen) is duplicated, the copy given to the left group; a quadratic mesh's mid-side nodes of
    the path edges likewise. The copies carry the original node's displacements in every step and
    new labels above the largest. Elsewhere the mesh stays conforming."""
    quads = np.array(mesh.quads)
    patches = None if mesh.patches is None else np.array(mesh.patches)
    edges, edge_of = _edges(quads)
    path = _crack_path(mesh, crack, key, edges)
    xy = mesh.nodes[:, :2]
    centroid = xy[quads].mean(axis=1)
    path_edges = {tuple(sorted(e)) for e in zip(path[:-1], path[1:])}
    row = {tuple(e): i for i, e in enumerate(edges.tolist()) if tuple(e) in path_edges}
    left, right = set(), set()
    elements_of_edge = {i: [] for i in row.values()}
    for e, k in zip(*np.nonzero(np.isin(edge_of, list(row.values())))):
        elements_of_edge[int(edge_of[e, k])].append((int(e), int(k)))
    for p, q in zip(path[:-1], path[1:]):
        owners = elements_of_edge[row[tuple(sorted((p, q)))]]
        d = xy[q] - xy[p]
        cross = [d[0] * (centroid[e, 1] - xy[p, 1]) - d[1] * (centroid[e, 0] - xy[p, 0]) for e, _ in owners]
        lefts = [o for o, c in zip(owners, cross) if c > 0]
        rights = [o for o, c in zip(owners, cross) if c <= 0]
        check(len(lefts) == 1 and len(rights) == 1, key,
              f"runs along an edge with {len(owners)} element(s) (node labels {int(mesh.node_labels[p])}–"
              f"{int(mesh.node_labels[q])}): the specimen's boundary, or not a sheet over the XY plane",
              "give a crack across the inside of a sheet lying over the specimen's XY plane")
        left.add(lefts[0])
        right.add(rights[0])
    left_elements = {e for e, _ in left}
    copies: list[int] = []                    # source node of each new node
    replace: dict[int, dict[int, int]] = {}   # element → {old node: new node}
    n = mesh.n_nodes
    order = np.argsort(quads.ravel(), kind="stable")     # node → its elements, by one sort
    first = np.searchsorted(quads.ravel()[order], np.arange(n + 1))
    for node in path:
        around = np.unique(order[first[node]:first[node + 1]] // 4)
        groups = _fan_groups(quads, around, node, path_edges)
        lefts = [g for g in groups if g & left_elements]
        if not lefts or len(lefts) == len(groups):
            continue                          # a tip inside the specimen: the fan stays whole
        new = n + len(copies)
        copies.append(node)
        for g in lefts:
            for e in g:
                replace.setdefault(e, {})[node] = new
    if patches is not None:                   # the path edges' mid-side nodes
        for e, k in left:
            mid = int(patches[e, 4 + k])
            new = n + len(copies)
            copies.append(mid)
            replace.setdefault(e, {})[mid] = new
    for e, swap in replace.items():
        for old, new in swap.items():
            quads[e][quads[e] == old] = new
            if patches is not None:
                patches[e, :8][patches[e, :8] == old] = new
                if patches[e, 8] == old:
                    patches[e, 8] = new
    source = np.concatenate([np.arange(n), np.asarray(copies, dtype=np.int64)])
    labels = np.concatenate([mesh.node_labels, mesh.node_labels.max() + 1 + np.arange(len(copies))])
    split = dataclasses.replace(mesh, nodes=mesh.nodes[source], quads=quads, node_labels=labels,
                                displacements=tuple(u[source] for u in mesh.displacements), patches=patches)
    s, _, cross, _ = _segment(split.nodes[:, :2], np.asarray(crack.start), np.asarray(crack.end))
    side = np.where(cross > 0, 1, -1)
    for group, sign in ((right, -1), (left, 1)):   # the elements along the path: their side of the path
        nodes = np.unique(np.concatenate([split.quads[e] if patches is None else split.patches[e]
                                          for e, _ in group]))
        nodes = nodes[nodes >= 0]                 # not a Q8/T6 centre code
        side[nodes] = sign
    side[np.asarray(path)] = -1                   # the originals stay with the right side
    side[n:] = 1
    duplicated = set(copies)
    return Split(split, side, source, (path[0] not in duplicated, path[-1] not in duplicated))


def _fan_groups(quads: np.ndarray, around: np.ndarray, node: int, cut: set) -> list[set[int]]:
    """The elements ``around`` ``node`` in groups that stay joined through edges at ``node`` not in ``cut``."""
    parent = {int(e): int(e) for e in around}

    def root(e):
        while parent[e] != e:
            e = parent[e]
        return e

    by_neighbour: dict[int, list[int]] = {}
    for e in around:
        q = quads[e].tolist()
        for k in range(4):
            if q[k] != node:
                continue
            for m in (q[k - 1], q[(k + 1) % 4]):
                if m != node and tuple(sorted((node, m))) not in cut:
                    by_neighbour.setdefault(m, []).append(int(e))
    for members in by_neighbour.values():
        for e in members[1:]:
            parent[root(e)] = root(members[0])
    groups: dict[int, set[int]] = {}
    for e in parent:
        groups.setdefault(root(e), set()).add(e)
    return list(groups.values())


def crack_displacement(crack: Crack, split: Split, X: np.ndarray) -> np.ndarray:
    """The crack's field (N, 3) at the split mesh's nodes X: opening·p(s)·exp(−d²/2h²) on the left
    side, 0 on the right; p(s) = (2√(s(L − s))/L with two tips inside, √(s/L) or √((L − s)/L) with
    one, 1 with none)."""
    s, d, _, L = _segment(X[:, :2], np.asarray(crack.start), np.asarray(crack.end))
    start_tip, end_tip = split.tips
    p = np.ones(len(X))
    if start_tip:
        p *= np.sqrt(s / L)
    if end_tip:
        p *= np.sqrt((L - s) / L)
    if start_tip and end_tip:
        p *= 2.0
    h = crack.decay or L
    w = p * np.exp(-d ** 2 / (2 * h * h)) * (split.side > 0)
    return w[:, None] * np.asarray(crack.opening)


# --- the whole field ----------------------------------------------------------------------

def px_per_mm(camera: Camera, R, t, X: np.ndarray, key: str = "specimen.field.max_displacement_px") -> np.ndarray:
    """fx/Z per specimen-frame node X (N, 3): camera-0 pixels per mm of in-plane motion there."""
    world = np.asarray(X, dtype=np.float64) @ np.asarray(R, float).T + np.asarray(t, float)
    z = (world @ camera.rotation.T + camera.translation)[:, 2]
    check(bool((z > 0).all()), key, f"{int((z <= 0).sum())} nodes lie behind camera {camera.name} (Z ≤ 0)",
          "place the specimen in front of camera 0 (specimen.pose), or remove max_displacement_px")
    return camera.fx / z


def field_displacement(field: Field, mesh: Mesh, scale=None) -> tuple[Mesh, np.ndarray]:
    """The mesh split along the field's cracks, and the field (N, 3) mm at its nodes (specimen
    frame): the components summed, then scaled by ``max_displacement_px`` (``scale(nodes)`` gives
    camera-0 px per mm at each node; needed then)."""
    sides = []
    for i, crack in enumerate(field.cracks):
        split = split_along(mesh, crack, f"specimen.field.cracks[{i}]")
        sides = [(c, dataclasses.replace(sp, side=sp.side[split.source])) for c, sp in sides]
        sides.append((crack, split))
        mesh = split.mesh
    X = mesh.nodes
    lo, hi = box(X)
    u = np.zeros((len(X), 3))
    if field.random is not None:
        work = len(X) * field.random.features * 3
        check(work <= MAX_FIELD_WORK, "specimen.field.random.features", f"{field.random.features} cosines at "
              f"{len(X)} nodes is {work:.3g} evaluations, more than {MAX_FIELD_WORK:.3g}", "use fewer features")
        u += random_displacement(field.random, field.seed, X)
    if field.affine is not None:
        u += affine_displacement(field.affine, field.seed, X, lo, hi)
    bumps = field.bumps + (drawn_bumps(field.random_bumps, field.seed, lo, hi) if field.random_bumps else ())
    check(len(bumps) * len(X) <= MAX_FIELD_WORK, "specimen.field.bumps", f"{len(bumps)} bumps at {len(X)} nodes "
          f"is more than {MAX_FIELD_WORK:.3g} evaluations", "use fewer bumps")
    u += bump_displacement(bumps, X)
    for crack, split in sides:
        u += crack_displacement(crack, split, X)
    target = drawn_scale(field)
    if target > 0:
        px = np.hypot(u[:, 0], u[:, 1]) * scale(X)
        largest = float(px.max())
        check(largest > 0, "specimen.field.max_displacement_px", "the field has no in-plane displacement to scale",
              "give a field with u or v, or remove max_displacement_px")
        u *= target / largest
    return mesh, u


def apply_field(field: Field, mesh: Mesh, scale=None) -> Mesh:
    """``mesh`` (specimen frame, mm) split along the field's cracks, with the field added to every
    load step after 0, or as load step 1 where there is none."""
    mesh, u = field_displacement(field, mesh, scale)
    steps = mesh.displacements
    if len(steps) > 1:
        return dataclasses.replace(mesh, displacements=(steps[0], *(s + u for s in steps[1:])))
    times = mesh.step_times + (None,) if mesh.step_times else ()
    return dataclasses.replace(mesh, displacements=(steps[0], u), step_times=times)
