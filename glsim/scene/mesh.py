"""Specimen surface meshes: Q4 quads with per-step nodal displacements.

Every surface element is a bilinear Q4 quad with nodes in counter-clockwise FE order

    node 0 at (ξ, η) = (−1, −1), 1 at (1, −1), 2 at (1, 1), 3 at (−1, 1),

    Φ0 = (1−ξ)(1−η)/4, Φ1 = (1+ξ)(1−η)/4, Φ2 = (1+ξ)(1+η)/4, Φ3 = (1−ξ)(1+η)/4.

The reference paper numbers nodes 3 and 4 (1-based) the other way round
(its Φ3 = (1−ξ)(1+η), Φ4 = (1+ξ)(1+η)); glsim keeps the FE order above.

A linear triangle (a, b, c) is stored as the collapsed quad (a, b, c, c). Because the
deformed and undeformed states use the same bilinear shape functions, this reproduces
linear-triangle interpolation exactly: λa = Φ0, λb = Φ1, λc = Φ2 + Φ3 are the barycentric
coordinates of the mapped point.

Units are millimetres; nodes and displacements are in the world frame.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from glsim.errors import SceneError
from glsim.limits import MAX_COORDINATE_MM

UNITS_TO_MM = {"mm": 1.0, "m": 1000.0, "cm": 10.0, "um": 1e-3, "in": 25.4}



def _frozen(array, dtype) -> np.ndarray:
    out = np.array(array, dtype=dtype, copy=True)
    out.setflags(write=False)
    return out


@dataclass(frozen=True, eq=False)
class Mesh:
    """Surface mesh in the world frame (mm).

    nodes (N,3) float64; quads (M,4) int64 node indices in FE order; node_labels (N,) and
    element_labels (M,) int64 as in the source file; displacements: one (N,3) float64
    array (mm) per load step, step 0 = undeformed (all zeros). Leaving displacements
    empty gives the single zero step. Arrays are stored as read-only copies.
    step_times: the solver's time of each load step where the source stores one (an
    Exodus II / .pvd / XDMF time series), None for a step without one; empty otherwise.
    patches: None for a linear mesh; for a quadratic one (M, 9) int64, each element as a
    9-node biquadratic patch (:mod:`glsim.scene.quadratic`: corners, mid-sides, centre or a
    derived-centre code); its first four columns are ``quads``.
    """

    nodes: np.ndarray
    quads: np.ndarray
    node_labels: np.ndarray
    element_labels: np.ndarray
    displacements: tuple[np.ndarray, ...] = ()
    step_times: tuple[float | None, ...] = ()
    patches: np.ndarray | None = None

    def __post_init__(self):
        nodes = np.asarray(self.nodes)
        if nodes.ndim != 2 or nodes.shape[1] != 3 or len(nodes) == 0:
            raise SceneError("mesh.nodes", f"shape {nodes.shape} is not (N, 3)", "give 3-D node coordinates")
        if not np.isfinite(nodes).all():
            raise SceneError("mesh.nodes", f"{np.count_nonzero(~np.isfinite(nodes))} coordinates are not finite",
                             "remove NaN/inf coordinates")
        check_bounded(nodes, self.node_labels, "mesh.nodes", "node label {label} lies at {row} mm", "coordinates (after specimen.mesh.unit and "
                      "specimen.pose)")
        n = len(nodes)
        quads = np.asarray(self.quads)
        if quads.ndim != 2 or quads.shape[1] != 4 or len(quads) == 0:
            raise SceneError("mesh.quads", f"shape {quads.shape} is not (M, 4)", "give at least one 4-node element")
        if not np.issubdtype(quads.dtype, np.integer):
            raise SceneError("mesh.quads", f"dtype {quads.dtype} is not an integer type", "give node indices")
        if quads.min() < 0 or quads.max() >= n:
            raise SceneError("mesh.quads", f"node indices span {quads.min()}..{quads.max()}, outside 0..{n - 1}",
                             "index into nodes (0-based)")
        for name, labels, count in (("node_labels", self.node_labels, n),
                                    ("element_labels", self.element_labels, len(quads))):
            if np.shape(labels) != (count,):
                raise SceneError(f"mesh.{name}", f"shape {np.shape(labels)} is not ({count},)", "give one label each")
        if len(np.unique(self.node_labels)) != n:
            raise SceneError("mesh.node_labels", "labels are not unique", "give every node its own label")
        steps = tuple(self.displacements) or (np.zeros((n, 3)),)
        for k, u in enumerate(steps):
            u = np.asarray(u)
            if u.shape != (n, 3):
                raise SceneError(f"mesh.displacements[{k}]", f"load step {k} has shape {u.shape}, not ({n}, 3)",
                                 "give one (N, 3) array (ux, uy, uz per node) per step")
            check_finite(u, np.asarray(self.node_labels), f"mesh.displacements[{k}]", f"load step {k}")
            check_bounded(u, self.node_labels, f"mesh.displacements[{k}]", f"load step {k} moves node label {{label}} by {{row}} mm",
                          "displacements (in specimen.mesh.unit)")
        if np.any(np.asarray(steps[0]) != 0):
            raise SceneError("mesh.displacements[0]", "step 0 is not all zeros",
                             "step 0 is the undeformed state; use with_displacements() to prepend it")
        times = tuple(None if t is None else float(t) for t in self.step_times)
        if times and len(times) != len(steps):
            raise SceneError("mesh.step_times", f"{len(times)} times for {len(steps)} load steps",
                             "give one time (or None) per load step, or none at all")
        set_ = object.__setattr__
        if self.patches is not None:
            set_(self, "patches", _frozen(_check_patches(self.patches, quads, n), np.int64))
        set_(self, "step_times", times)
        set_(self, "nodes", _frozen(nodes, np.float64))
        set_(self, "quads", _frozen(quads, np.int64))
        set_(self, "node_labels", _frozen(self.node_labels, np.int64))
        set_(self, "element_labels", _frozen(self.element_labels, np.int64))
        set_(self, "displacements", tuple(_frozen(u, np.float64) for u in steps))

    @property
    def is_quadratic(self) -> bool:
        """Whether the elements are quadratic patches (``patches`` set)."""
        return self.patches is not None

    @property
    def n_steps(self) -> int:
        """Number of load steps, including the undeformed step 0."""
        return len(self.displacements)

    @property
    def n_nodes(self) -> int:
        return len(self.nodes)

    @property
    def n_elements(self) -> int:
        return len(self.quads)

    def deformed(self, step: int) -> np.ndarray:
        """Node positions (N,3) mm at load step `step` (0 = undeformed)."""
        if not 0 <= step < self.n_steps:
            raise SceneError("step", f"{step} is outside 0..{self.n_steps - 1}", "pick an existing load step")
        return self.nodes + self.displacements[step]


def _check_patches(patches, quads: np.ndarray, n: int) -> np.ndarray:
    p = np.asarray(patches)
    if p.ndim != 2 or p.shape != (len(quads), 9) or not np.issubdtype(p.dtype, np.integer):
        raise SceneError("mesh.patches", f"shape {p.shape} ({p.dtype}) is not ({len(quads)}, 9) integers",
                         "give one row of 9 node indices (corners, mid-sides, centre) per element")
    bad = (p[:, :8] < 0) | (p[:, :8] >= n)
    centre = p[:, 8]
    bad_centre = ~(((centre >= 0) & (centre < n)) | (centre == -1) | (centre == -2))   # glsim.scene.quadratic's derived centres
    if bad.any() or bad_centre.any():
        row = int(np.flatnonzero(bad.any(axis=1) | bad_centre)[0])
        raise SceneError("mesh.patches", f"element {row} refers to node indices {p[row].tolist()}, outside 0..{n - 1} "
                         "(a quadratic element with a missing node?)", "give every corner and mid-side node")
    if not np.array_equal(p[:, :4], quads):
        raise SceneError("mesh.patches", "the first four columns differ from quads",
                         "give the corners in both, in the same order")
    return p


def check_finite(u: np.ndarray, node_labels: np.ndarray, key: str, what: str) -> None:
    """Raise SceneError naming ``what``, the count and the first node label where the (N, 3)
    displacement ``u`` is NaN or infinite."""
    bad = ~np.isfinite(np.asarray(u, dtype=np.float64)).all(axis=1)
    if bad.any():
        first = np.flatnonzero(bad)[0]
        label = node_labels[first] if np.shape(node_labels) == (len(u),) else first + 1
        raise SceneError(key, f"{what} has non-finite (NaN or inf) displacements at {int(bad.sum())} of "
                         f"{len(u)} nodes, first at node label {int(label)}: {np.asarray(u)[first].tolist()}",
                         "give finite numbers for every node (0 where a node does not move)")


def check_bounded(a: np.ndarray, node_labels, key: str, what: str, fix: str) -> None:
    """Raise SceneError naming the first node whose row of the finite (N, 3) array ``a`` (mm) has an
    entry beyond ±MAX_COORDINATE_MM (:mod:`glsim.limits`): e.g. 1e300 mm, whose squares overflow.
    ``what`` says it, with ``{label}`` and ``{row}`` filled in."""
    a = np.asarray(a, dtype=np.float64)
    if not len(a) or float(np.abs(a).max()) <= MAX_COORDINATE_MM:
        return
    bad = np.abs(a).max(axis=1) > MAX_COORDINATE_MM
    first = int(np.flatnonzero(bad)[0])
    label = node_labels[first] if np.shape(node_labels) == (len(a),) else first + 1
    raise SceneError(key, what.format(label=int(label), row=a[first].tolist()) + f" ({int(bad.sum())} of {len(a)} "
                     f"nodes beyond glsim's limit of ±{MAX_COORDINATE_MM:g} mm)",
                     f"check the {fix}: the specimen must lie within {MAX_COORDINATE_MM:g} mm of the world origin")


def with_displacements(mesh: Mesh, steps: Sequence[np.ndarray]) -> Mesh:
    """New Mesh with displacements (zeros, *steps): `steps` are load steps 1..n, (N,3) mm
    (and no step times)."""
    return dataclasses.replace(mesh, displacements=(np.zeros((mesh.n_nodes, 3)), *steps), step_times=())


# --- units and placement ----------------------------------------------------------------

def place(nodes, unit: str, R=None, t=None) -> np.ndarray:
    """Scale `nodes` (…,3) from `unit` to mm, then X_world = R·X + t (R rotation, t in mm).

    For displacements pass t=None: they are scaled and rotated only.
    """
    if unit not in UNITS_TO_MM:
        raise SceneError("specimen.unit", f"unknown unit {unit!r}", f"use one of {', '.join(UNITS_TO_MM)}")
    out = np.asarray(nodes, dtype=np.float64) * UNITS_TO_MM[unit]
    if R is not None:
        R = np.asarray(R, dtype=np.float64)
        if (R.shape != (3, 3) or not np.isfinite(R).all() or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
                or np.linalg.det(R) < 0):
            raise SceneError("specimen.R", "is not a 3×3 rotation matrix (RᵀR = I, det R = +1)",
                             "give a proper rotation (no scaling or mirroring)")
        out = out @ R.T
    if t is not None:
        t = np.asarray(t, dtype=np.float64)
        if t.shape != (3,) or not np.isfinite(t).all():
            raise SceneError("specimen.t", f"shape {t.shape} is not a finite 3-vector", "give [tx, ty, tz] in mm")
        out = out + t
    return out


def place_mesh(mesh: Mesh, unit: str = "mm", R=None, t=None) -> Mesh:
    """Mesh with nodes placed by place() and displacements scaled and rotated alike."""
    return dataclasses.replace(mesh, nodes=place(mesh.nodes, unit, R, t),
                               displacements=tuple(place(u, unit, R) for u in mesh.displacements))


def quad_normals(nodes: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Quad normals (M,3) = (x2 − x0) × (x3 − x1); for flat quads and collapsed quads
    (triangles) the length is twice the area."""
    x = nodes[quads]
    return np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])


# --- built-in specimens -----------------------------------------------------------------

def _positive(key: str, value, integer: bool = False):
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = np.nan
    if not (np.isfinite(v) and v > 0 and (not integer or v.is_integer())):
        raise SceneError(f"specimen.{key}", f"{value!r} is not a positive {'integer' if integer else 'number'}",
                         f"give {key} > 0")
    return int(v) if integer else v


def _grid_quads(index: np.ndarray) -> np.ndarray:
    """Quads (M,4) of a structured grid of node indices (rows, cols): CCW when cols run
    along the first in-plane axis and rows along the second."""
    return np.stack([index[:-1, :-1], index[:-1, 1:], index[1:, 1:], index[1:, :-1]], axis=-1).reshape(-1, 4)


def _generated(nodes: np.ndarray, quads: np.ndarray) -> Mesh:
    return Mesh(nodes, quads, np.arange(1, len(nodes) + 1), np.arange(1, len(quads) + 1))


def plate(width: float, height: float, nx: int, ny: int, center=(0.0, 0.0, 0.0)) -> Mesh:
    """Flat width × height (mm) rectangle in the plane z = center[2], nx × ny Q4 elements, CCW from +z."""
    width, height = _positive("width", width), _positive("height", height)
    nx, ny = _positive("nx", nx, integer=True), _positive("ny", ny, integer=True)
    x, y = np.meshgrid(np.linspace(-width / 2, width / 2, nx + 1), np.linspace(-height / 2, height / 2, ny + 1))
    nodes = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1) + np.asarray(center, dtype=np.float64)
    return _generated(nodes, _grid_quads(np.arange(x.size).reshape(x.shape)))


def disc(radius: float, n_core: int = 8, n_ring: int = 8) -> Mesh:
    """Flat disc of `radius` (mm) at the origin in z = 0, O-grid meshed, quads CCW from +z.

    A central square of n_core × n_core quads, of half-size a chosen so its elements match
    the first ring layer (a = R·n_core/(n_core + 2·n_ring), clipped to 0.2R..0.4R), plus
    n_ring layers of 4·n_core quads blending linearly from the square to the circle; the
    square's boundary nodes map to equally spaced angles on the circle.
    """
    radius = _positive("radius", radius)
    n, n_ring = _positive("n_core", n_core, integer=True), _positive("n_ring", n_ring, integer=True)
    a = radius * np.clip(n / (n + 2 * n_ring), 0.2, 0.4)
    s = np.linspace(-a, a, n + 1)
    x, y = np.meshgrid(s, s)
    core = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)  # core[j, i] at (s[i], s[j])
    t = np.arange(n)
    # square boundary CCW from the corner (a, −a): right, top, left, bottom sides
    perimeter = np.concatenate([core[t, n], core[n, n - t], core[n - t, 0], core[0, t]])
    theta = -np.pi / 4 + np.arange(4 * n) * np.pi / (2 * n)
    inner = np.stack([x.ravel(), y.ravel()], axis=1)[perimeter]
    outer = radius * np.stack([np.cos(theta), np.sin(theta)], axis=1)
    f = (np.arange(1, n_ring + 1) / n_ring)[:, None, None]
    ring_xy = (inner + f * (outer - inner)).reshape(-1, 2)
    xy = np.concatenate([np.stack([x.ravel(), y.ravel()], axis=1), ring_xy])
    layers = np.concatenate([perimeter[None], core.size + np.arange(n_ring * 4 * n).reshape(n_ring, 4 * n)])
    ring_index = np.concatenate([layers, layers[:, :1]], axis=1).T  # rows: perimeter position, cols: layer
    quads = np.concatenate([_grid_quads(core), _grid_quads(ring_index)])
    return _generated(np.pad(xy, ((0, 0), (0, 1))), quads)


def bulge_displacements(nodes, radius: float, w0: float, n_steps: int, thickness: float,
                        direction=(0.0, 0.0, -1.0)) -> tuple[np.ndarray, ...]:
    """Analytic bulge-test field (mm) of the viewed plate surface, for load steps 1..n_steps.

    Kirchhoff clamped circular plate shape w(r) = w_k·(1 − r²/R²)² (0 for r ≥ R), with the
    amplitude prescribed: w_k = w0·k/n_steps. Linear theory would give w0 = pR⁴/(64D) ≈
    2.24 mm for the paper's p = 11.9 MPa, E = 210 GPa, ν = 0.3, t = 3 mm, R = 50 mm; its
    5 mm comes from a non-linear FE model, so glsim prescribes the amplitude.

    `direction` (unit vector, default (0,0,−1): towards a camera on the −z side looking
    along +z) is where the plate bulges; r is the distance from the axis through the
    origin along it. The viewed surface is the convex one, thickness/2 from the
    mid-plane: it moves w along `direction` and u_r = −(thickness/2)·dw/dr radially
    (outwards, i.e. stretched, near the centre). Returns one (N,3) array per step;
    use with_displacements() to prepend step 0.
    """
    radius, w0, n_steps = _positive("radius", radius), float(w0), _positive("n_steps", n_steps, integer=True)
    thickness = float(thickness)
    if not (np.isfinite(w0) and np.isfinite(thickness) and thickness >= 0):
        raise SceneError("specimen", f"w0={w0!r}, thickness={thickness!r} are not finite (thickness ≥ 0)",
                         "give finite w0 and a non-negative thickness in mm")
    d = np.asarray(direction, dtype=np.float64)
    if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) == 0:
        raise SceneError("specimen.direction", f"{direction!r} is not a non-zero 3-vector", "give e.g. [0, 0, -1]")
    d = d / np.linalg.norm(d)
    nodes = np.asarray(nodes, dtype=np.float64)
    r_vec = nodes - np.outer(nodes @ d, d)
    r = np.linalg.norm(r_vec, axis=1)
    e_r = np.divide(r_vec, r[:, None], out=np.zeros_like(r_vec), where=r[:, None] > 0)
    s = np.clip(1 - (r / radius) ** 2, 0.0, None)
    shape, dshape_dr = s ** 2, -4 * r / radius ** 2 * s
    unit = np.outer(shape, d) - thickness / 2 * dshape_dr[:, None] * e_r
    return tuple(w0 * k / n_steps * unit for k in range(1, n_steps + 1))


def bulge(radius: float = 50.0, thickness: float = 3.0, w0: float = 5.0, n_steps: int = 3,
          n_core: int = 8, n_ring: int = 8, direction=(0.0, 0.0, -1.0)) -> Mesh:
    """The built-in bulge specimen: disc() with bulge_displacements(), steps 0..n_steps (mm)."""
    mesh = disc(radius, n_core, n_ring)
    return with_displacements(mesh, bulge_displacements(mesh.nodes, radius, w0, n_steps, thickness, direction))
