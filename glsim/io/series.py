"""FE results with several stored time steps → :class:`~glsim.scene.mesh.Mesh`, one load step
per stored time: Exodus II (:mod:`glsim.io.exodus`), ParaView ``.pvd`` collections of ``.vtu``
files and XDMF time series (meshio's ``TimeSeriesReader``).

Each reader opens its file as a :class:`Series` (mesh, node/element labels, stored times, and
the nodal fields, read lazily per time); :func:`glsim.io.fe.load_series` picks the displacement fields and
the times, and builds the surface with the outer-face logic of :mod:`glsim.io.meshfiles`.

Load steps: the undeformed mesh is step 0. If the first selected time has zero displacement
everywhere (a solver's initial state, e.g. MOOSE's t = 0), it *is* step 0 and the k-th
selected time is step k; otherwise an undeformed step 0 (no solver time) is put in front
and the k-th selected time is step k + 1. ``Mesh.step_times`` records each step's time.
"""
from __future__ import annotations

import contextlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Callable, Iterator, Sequence

import meshio
import numpy as np

from glsim.errors import SceneError
from glsim.io.meshfiles import QUADRATIC_CELLS, SOLID_FIX, as_xyz, check_node_range, meshio_read, surface_from_cells
from glsim.io.xdmfcheck import check_xdmf, is_temporal_xdmf
from glsim.scene.model import TIME_SERIES_SUFFIXES

__all__ = ["Series", "is_time_series"]

LINEAR_CELLS = ("quad", "triangle", "hexahedron", "tetra")
IGNORED_CELLS = ("line", "vertex", "line3")
QUADRATIC_FIX = ("these quadratic elements are not supported: use QUAD8/QUAD9, TRI6, TETRA10, HEX20, HEX27 or "
                 "WEDGE15 (meshio's names: quad8/quad9, triangle6, tetra10, hexahedron20/27), or a linear mesh")
# Usual spellings of displacement components / vectors, tried in order when none is named.
COMPONENT_PREFIXES = ("disp_", "displacement_", "displ", "disp", "u_", "u")
VECTOR_NAMES = ("displacement", "displacements", "disp", "u")


@dataclass
class Series:
    """One opened time-series file.

    points (N,3) in file units; dim: the file's spatial dimension (2 or 3); cells: meshio
    cell blocks (type, 0-based connectivity, meshio/VTK node order), quadratic ones included;
    cell_labels: the file's element numbers per block; node_labels (N,); times (T,) the
    stored times; fields: nodal field name → components (1 = scalar, 2 or 3 = vector);
    read(name, k): that field at stored step k, (N,) or (N, c).
    """
    path: Path
    points: np.ndarray
    dim: int
    cells: list[tuple[str, np.ndarray]]
    cell_labels: list[np.ndarray]
    node_labels: np.ndarray
    times: np.ndarray
    fields: dict[str, int]
    read: Callable[[str, int], np.ndarray]
    block_names: list[str] | None = None

    def summary(self) -> str:
        """'fields in case.e: disp_x, disp_y, …; times 0–200, 41 steps' (what the file has)."""
        names = list(self.fields)
        listed = ", ".join(names[:25]) + (f", … ({len(names)} in all)" if len(names) > 25 else "")
        return f"fields in {self.path.name}: {listed or 'none'}; {times_text(self.times)}"


def times_text(times: np.ndarray) -> str:
    if len(times) == 0:
        return "no stored time steps"
    if len(times) == 1:
        return f"time {times[0]:g}, 1 step"
    return f"times {times.min():g}–{times.max():g}, {len(times)} steps"


def is_time_series(path) -> bool:
    """Whether `path` is read by :func:`load_series`: an Exodus II file, a .pvd collection, or an
    XDMF file holding a temporal collection (a single-state XDMF file is read by meshio)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".xdmf", ".xmf"):
        return is_temporal_xdmf(path)
    return suffix in TIME_SERIES_SUFFIXES


# --- ParaView .pvd ----------------------------------------------------------------------

def _read_vtk(path: Path, pvd: Path):
    if not path.is_file():
        raise SceneError(str(pvd), f"lists {path.name}, which does not exist", "keep the .vtu files beside the .pvd")
    try:
        return meshio_read(path)
    except Exception as exc:
        raise SceneError(str(path), f"meshio could not read it ({type(exc).__name__}: {exc})",
                         "list .vtu/.vtk files in the .pvd collection (not .pvtu)") from exc


def _point_fields(point_data: dict, n: int) -> dict[str, int]:
    fields = {}
    for name, array in point_data.items():
        shape = np.shape(array)
        if len(shape) >= 1 and shape[0] == n and (len(shape) == 1 or (len(shape) == 2 and shape[1] <= 3)):
            fields[name] = 1 if len(shape) == 1 else shape[1]
    return fields


def open_pvd(path: Path) -> Series:
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise SceneError(str(path), f"is not valid XML ({exc})", "give a ParaView .pvd collection") from None
    sets = root.findall("./Collection/DataSet")
    if root.tag != "VTKFile" or root.get("type") != "Collection" or not sets:
        raise SceneError(str(path), "is not a ParaView collection (no VTKFile type=\"Collection\" with DataSet entries)",
                         "give a .pvd file as ParaView writes it")
    entries = []
    for i, ds in enumerate(sets):
        if ds.get("file") is None:
            raise SceneError(str(path), f"DataSet {i + 1} has no file attribute", "give file=\"step_0.vtu\"")
        if ds.get("part", "0") not in ("0", ""):
            raise SceneError(str(path), f"DataSet {ds.get('file')} is part {ds.get('part')} of a step: "
                             "multi-part (parallel) collections are not supported",
                             "write one .vtu per time step (e.g. merge the parts in ParaView)")
        try:
            t = float(ds.get("timestep", i))
        except ValueError:
            raise SceneError(str(path), f"DataSet {ds.get('file')} has timestep {ds.get('timestep')!r}",
                             "give numeric timesteps") from None
        entries.append((t, path.parent / ds.get("file")))
    entries.sort(key=lambda e: e[0])
    times = np.array([t for t, _ in entries])
    files = [f for _, f in entries]
    first = _read_vtk(files[0], path)
    points = np.asarray(first.points, dtype=np.float64)
    n = len(points)
    cache = {0: first}

    def read(name: str, k: int) -> np.ndarray:
        if k not in cache:
            cache.clear()
            raw = _read_vtk(files[k], path)
            if len(raw.points) != n or not np.allclose(raw.points, points, rtol=0, atol=1e-9 * np.ptp(points)):
                raise SceneError(str(files[k]), f"its {len(raw.points)} nodes differ from the {n} of {files[0].name}",
                                 "give a time series on one fixed mesh (no remeshing)")
            cache[k] = raw
        data = cache[k].point_data
        if name not in data:
            raise SceneError(str(files[k]), f"has no point data {name!r} at time {times[k]:g} "
                             f"(has: {', '.join(data) or 'none'})", "write the field at every time step")
        return np.asarray(data[name])

    return Series(path=path, points=as_xyz(points), dim=_planar_dim(points),
                  cells=[(b.type, np.asarray(b.data, dtype=np.int64)) for b in first.cells],
                  cell_labels=_ordinal_labels(first.cells),
                  node_labels=_node_labels(first.point_data, n),
                  times=times, fields=_point_fields(first.point_data, n), read=read)


def _planar_dim(points: np.ndarray) -> int:
    """2 for points with two coordinates or all z = 0, else 3."""
    points = np.asarray(points)
    return 2 if points.shape[1] == 2 or not np.any(points[:, 2]) else 3


def _ordinal_labels(cells) -> list[np.ndarray]:
    ordinals = np.cumsum([0] + [len(b.data) for b in cells]) + 1
    return [np.arange(ordinals[i], ordinals[i + 1]) for i in range(len(cells))]


def _node_labels(point_data: dict, n: int) -> np.ndarray:
    for name in ("node_id", "label"):
        if name in point_data and np.size(point_data[name]) == n:
            return np.asarray(point_data[name]).reshape(n).astype(np.int64)
    return np.arange(1, n + 1)


# --- XDMF: what its DataItems declare, bounded before meshio reads them ------------------

@contextlib.contextmanager
def open_xdmf(path: Path) -> Iterator[Series]:
    """An XDMF time series as a :class:`Series`, its DataItems bounded first (:func:`check_xdmf`) and
    its elements' node indices checked against its nodes once read."""
    check_xdmf(path)
    try:
        reader = meshio.xdmf.TimeSeriesReader(path)
    except Exception as exc:
        raise SceneError(str(path), f"meshio could not read it as an XDMF time series ({type(exc).__name__}: {exc})",
                         "give an XDMF 3 file with a temporal collection (as meshio or FEniCS write it)") from exc
    with reader:
        try:
            points, cells = reader.read_points_cells()
        except Exception as exc:
            raise SceneError(str(path), f"meshio could not read its mesh ({type(exc).__name__}: {exc})",
                             "give an XDMF 3 file with a temporal collection (as meshio or FEniCS write it)") from exc
        points = np.asarray(points, dtype=np.float64)
        n = len(points)
        for block, labels in zip(cells, _ordinal_labels(cells)):
            check_node_range(path, np.asarray(block.data, dtype=np.int64), n, f"Topology: {block.type}", labels)
        times, fields = [], {}
        for k, grid in enumerate(reader.collection):
            time = grid.find("Time")
            try:
                times.append(float(time.get("Value")))
            except (AttributeError, TypeError, ValueError):
                raise SceneError(str(path), f"time step {k} of the collection has no <Time Value=…>",
                                 "write a time value for every step") from None
            for attr in grid.findall("Attribute"):
                if attr.get("Center") == "Node" and attr.get("Name") not in fields:
                    item = attr.find("DataItem")
                    dims = [int(d) for d in (item.get("Dimensions", "") if item is not None else "").split()]
                    if dims and dims[0] == n and len(dims) <= 2:
                        fields[attr.get("Name")] = 1 if len(dims) == 1 else dims[1]
        cache: dict[int, dict] = {}

        def read(name: str, k: int) -> np.ndarray:
            if k not in cache:
                cache.clear()
                try:
                    cache[k] = reader.read_data(k)[1]
                except Exception as exc:
                    raise SceneError(str(path), f"meshio could not read time {times[k]:g} "
                                     f"({type(exc).__name__}: {exc})", "check the file and its .h5 data") from exc
            if name not in cache[k]:
                raise SceneError(str(path), f"has no nodal field {name!r} at time {times[k]:g} "
                                 f"(has: {', '.join(cache[k]) or 'none'})", "write the field at every time step")
            return np.asarray(cache[k][name])

        yield Series(path=path, points=as_xyz(points), dim=_planar_dim(points),
                     cells=[(b.type, np.asarray(b.data, dtype=np.int64)) for b in cells],
                     cell_labels=_ordinal_labels(cells), node_labels=np.arange(1, n + 1),
                     times=np.asarray(times, dtype=np.float64), fields=fields, read=read)


# --- fields, times, surface -------------------------------------------------------------

def default_displacement(s: Series) -> tuple[str, ...]:
    """The displacement fields when the scene names none: a vector field called displacement/u/…,
    the only vector field, or component fields disp_x/disp_y(/disp_z), …"""
    vectors = [name for name, c in s.fields.items() if c in (2, 3)]
    lower = {name.lower(): name for name in s.fields}
    for name in VECTOR_NAMES:
        if name in lower and lower[name] in vectors:
            return (lower[name],)
    for prefix in COMPONENT_PREFIXES:
        comps = [lower.get(prefix + axis) for axis in "xyz"]
        if comps[0] and comps[1] and (comps[2] or s.dim == 2) and all(s.fields[c] == 1 for c in comps if c):
            return tuple(c for c in comps if c)   # a 2-D result has no z component: zero
    if len(vectors) == 1:
        return (vectors[0],)
    raise SceneError(str(s.path), "no displacement field found by name", "set [specimen.mesh] displacement = "
                     f"[\"ux\", \"uy\", \"uz\"] (component fields) or \"u\" (a vector field); {s.summary()}")


def check_displacement(s: Series, names: Sequence[str]) -> list[str | None]:
    """Validated displacement names: one vector field, or 2–3 scalar component fields (None:
    zero — an empty name, or a z component missing from a 2-D file)."""
    if len(names) == 1 and names[0]:
        name = names[0]
        if name not in s.fields:
            raise SceneError(str(s.path), f"no nodal field {name!r}; {s.summary()}",
                             "set [specimen.mesh] displacement to names from that list")
        if s.fields[name] == 1:
            raise SceneError(str(s.path), f"nodal field {name!r} is a scalar, not a displacement vector; {s.summary()}",
                             "name the component fields, e.g. displacement = [\"disp_x\", \"disp_y\", \"disp_z\"]")
        if s.fields[name] == 2 and s.dim == 3:
            raise SceneError(str(s.path), f"nodal field {name!r} has 2 components per node on a mesh that is "
                             "not plane (z = 0)", "write the displacement with 3 components; glsim does not guess "
                             "which plane 2 components lie in")
        return [name]
    out: list[str | None] = []
    for axis, name in zip("xyz", names):
        if not name:
            out.append(None)
        elif name in s.fields:
            if s.fields[name] != 1:
                raise SceneError(str(s.path), f"nodal field {name!r} has {s.fields[name]} components, not 1 "
                                 f"(the {axis} component); {s.summary()}",
                                 "give a vector field as the only name, or scalar component fields")
            out.append(name)
        elif axis == "z" and s.dim == 2:
            out.append(None)   # a 2-D result has no out-of-plane component
        else:
            raise SceneError(str(s.path), f"no nodal field {name!r} (the {axis} displacement); {s.summary()}",
                             "set [specimen.mesh] displacement to names from that list (\"\" for a zero component)")
    return out + [None] * (3 - len(out))


def displacement_at(s: Series, names: list[str | None], k: int) -> np.ndarray:
    """Displacement (N,3) in file units at stored step k."""
    n = len(s.points)
    u = np.zeros((n, 3))
    if len(names) == 1:
        value = np.asarray(s.read(names[0], k), dtype=np.float64)
        value = value.reshape(n, -1) if value.size % n == 0 else value
        if value.shape[0] != n or value.ndim != 2 or value.shape[1] not in (2, 3):
            raise SceneError(str(s.path), f"nodal field {names[0]!r} has shape {value.shape} at time "
                             f"{s.times[k]:g}, not ({n}, 3) or ({n}, 2)", "give a displacement vector per node")
        u[:, :value.shape[1]] = value
    else:
        for axis, name in enumerate(names):
            if name is not None:
                value = np.asarray(s.read(name, k), dtype=np.float64).reshape(-1)
                if value.shape != (n,):
                    raise SceneError(str(s.path), f"nodal field {name!r} has {value.size} values at time "
                                     f"{s.times[k]:g}, not one per node ({n})", "give one value per node")
                u[:, axis] = value
    bad = ~np.isfinite(u)
    if bad.any():
        rows = np.flatnonzero(bad.any(axis=1))
        first = ", ".join(str(label) for label in s.node_labels[rows[:5]])
        raise SceneError(str(s.path), f"displacement {'/'.join(n or '0' for n in names)} has non-finite values at "
                         f"time {s.times[k]:g} (stored step {k}) on {len(rows)} nodes (labels {first}"
                         f"{', …' if len(rows) > 5 else ''})", "select other times, or fix the result")
    return u


def select_steps(s: Series, times: Sequence[float], steps: Sequence[int]) -> list[int]:
    """Stored-step indices picked by `times` (the file's time values) or `steps` (indices,
    negative from the end); all by default."""
    n = len(s.times)
    if len(times) and len(steps):
        raise SceneError("specimen.mesh.times", "times and steps both given", "keep one of them")
    if len(steps):
        picked = []
        for i in steps:
            if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not -n <= i < n:
                raise SceneError(str(s.path), f"has no stored step {i!r}; {times_text(s.times)}",
                                 f"give steps as indices 0…{n - 1} (or -1 for the last)" if n else "remove steps")
            picked.append(int(i) % n)
        return picked
    if len(times):
        span = float(np.ptp(s.times)) if n else 0.0
        tol = 1e-9 * max(span, float(np.abs(s.times).max()) if n else 0.0, 1e-300)
        picked = []
        for t in times:
            hits = np.flatnonzero(np.abs(s.times - float(t)) <= tol) if n else []
            if not len(hits):
                near = (f" (nearest {s.times[np.argmin(np.abs(s.times - float(t)))]:g})" if n else "")
                raise SceneError(str(s.path), f"has no time {float(t):g}{near}; {times_text(s.times)}",
                                 "give times the file stores, or steps = [indices]")
            picked.append(int(hits[0]))
        return picked
    return list(range(n))


def series_surface(s: Series):
    """Surface quads, element labels and quadratic patches (or None); same-type solid blocks
    are merged first so faces shared between blocks are inner faces."""
    merged: dict[str, list] = {}
    for i, ((kind, conn), labels) in enumerate(zip(s.cells, s.cell_labels)):
        name = s.block_names[i] if s.block_names else f"cell block {i + 1}"
        if kind in IGNORED_CELLS or len(conn) == 0:
            continue
        if kind not in LINEAR_CELLS and kind not in QUADRATIC_CELLS:
            quadratic = any(kind.startswith(base) for base in LINEAR_CELLS) or kind == "line3"
            raise SceneError(str(s.path), f"{name} has {kind} elements" + (
                f" ({conn.shape[1]} nodes each): {QUADRATIC_FIX}" if quadratic else ", which are not supported"),
                "" if quadratic else SOLID_FIX)
        merged.setdefault(kind, []).append((conn, labels))
    if not merged:
        raise SceneError(str(s.path), "has no quad, triangle, hexahedron or tetra elements", SOLID_FIX)
    # (meshio's CellBlock has no wedge15: the blocks as the two fields surface_from_cells reads)
    blocks = [SimpleNamespace(type=kind, data=np.concatenate([c for c, _ in parts])) for kind, parts in merged.items()]
    labels = [np.concatenate([lab for _, lab in parts]) for parts in merged.values()]

    return surface_from_cells(s.path, SimpleNamespace(cells=blocks), s.points, labels)


