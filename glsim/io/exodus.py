"""Exodus II results (MOOSE, Cubit, SEACAS, …) read through netCDF4, every stored time step.

The netCDF layout of Exodus II (Sandia's "Exodus II: a finite element data model"):
dimensions ``num_nodes``, ``num_dim``, ``num_el_blk``, ``num_el_in_blk{i}``,
``num_nod_per_el{i}``, ``time_step``; variables ``coordx/coordy/coordz`` (or ``coord``
(num_dim, num_nodes)), ``connect{i}`` (1-based, attribute ``elem_type``), ``eb_names``,
``eb_prop1`` (block ids), ``node_num_map``, ``elem_num_map``, ``time_whole``,
``name_nod_var`` and ``vals_nod_var{j}`` (time_step, num_nodes) or ``vals_nod_var``
(time_step, num_nod_var, num_nodes).

Element types as solvers spell them: QUAD/QUAD4/SHELL/SHELL4, TRI/TRI3/TRISHELL3,
HEX/HEX8, TETRA/TETRA4/TET4 and the quadratic QUAD8, QUAD9 (SHELL8/9), TRI6, TETRA10 (node
orders as VTK's, so meshio's face tables apply), HEX20, whose Exodus (PATRAN) order puts
the four vertical mid-edge nodes before the top face's (nodes 13–16, 1-based) where VTK puts
them last, and HEX27: HEX20's order, then the centroid (21) and the face centres 22 z−
(side 5), 23 z+ (side 6), 24 x− (side 4), 25 x+ (side 2), 26 y− (side 1), 27 y+ (side 3) (SEACAS's
side-node table, nem_slice's ss_to_node_list), where VTK has the faces' centres 20–25 in the
order x−, x+, y−, y+, z−, z+ and the centroid last; WEDGE15, whose vertical mid-edge nodes
(10–12) come before the top triangle's (13–15), where VTK puts them last (the same table). These
three are permuted on reading. Other node counts (TRI7, TETRA14, WEDGE6 …) are refused by name
(their Exodus node order is not confirmed here, or glsim reads no such solid; VTU, Gmsh or
Abaqus files of them are read through meshio); bars, beams and spheres are ignored. Labels are
the file's own node and element numbers.

A classic netCDF file (CDF-1, CDF-2, CDF-5; not the HDF5-based netCDF-4) is checked before it is
read: every variable, and every stored step of the record variables, must lie inside the file,
so that a truncated file (netCDF reads the missing bytes as zeros) or a damaged record count
is refused naming the step, instead of giving a wrong image or a huge allocation. Every file,
netCDF-4 (HDF5) included, whose length bounds nothing, is then bounded by its dimensions: the
mesh they declare must fit in memory (:func:`~glsim.limits.check_mesh_memory`) and each variable's
shape must match them before it is read. A declared block without its ``connect{i}``, coordinates
never written (netCDF's fill value) or not finite, and a non-finite time are refused by name.
"""
from __future__ import annotations

import contextlib
import math
import re
from pathlib import Path
from typing import Iterator

import numpy as np

from glsim.errors import SceneError
from glsim.limits import check_mesh_memory
from glsim.io.series import QUADRATIC_FIX, Series
from glsim.io.meshfiles import SOLID_FIX

# element family → (meshio type, linear node count)
_LINEAR = {"QUAD": ("quad", 4), "SHELL": ("quad", 4), "QUADRILATERAL": ("quad", 4),
           "TRI": ("triangle", 3), "TRIANGLE": ("triangle", 3), "TRISHELL": ("triangle", 3),
           "HEX": ("hexahedron", 8), "HEXAHEDRON": ("hexahedron", 8),
           "TET": ("tetra", 4), "TETRA": ("tetra", 4), "TETRAHEDRON": ("tetra", 4)}
# quadratic (family, node count) → meshio type, and Exodus → VTK node permutation where they differ
_QUADRATIC = {("QUAD", 8): "quad8", ("SHELL", 8): "quad8", ("QUADRILATERAL", 8): "quad8",
              ("QUAD", 9): "quad9", ("SHELL", 9): "quad9", ("QUADRILATERAL", 9): "quad9",
              ("TRI", 6): "triangle6", ("TRIANGLE", 6): "triangle6", ("TRISHELL", 6): "triangle6",
              ("HEX", 20): "hexahedron20", ("HEXAHEDRON", 20): "hexahedron20",
              ("HEX", 27): "hexahedron27", ("HEXAHEDRON", 27): "hexahedron27",
              ("WEDGE", 15): "wedge15",
              ("TET", 10): "tetra10", ("TETRA", 10): "tetra10", ("TETRAHEDRON", 10): "tetra10"}
# (VTK node i is Exodus node EXODUS_TO_VTK[kind][i], 0-based)
EXODUS_TO_VTK = {"hexahedron20": np.r_[0:12, 16:20, 12:16],
                 "hexahedron27": np.r_[0:12, 16:20, 12:16, 23, 24, 25, 26, 21, 22, 20],
                 "wedge15": np.r_[0:9, 12:15, 9:12]}
MAX_NAME_LENGTH = 4096      # chars of one name (eb_names, name_nod_var): Exodus writes 33 or 256
MAX_NAMES = 100_000         # nodal variables named without a num_nod_var dimension
_NC_FILL_DOUBLE = 9.969209968386869e36    # netCDF's default fill value: a variable never written
_IGNORED = ("BAR", "BEAM", "TRUSS", "EDGE", "SPHERE", "CIRCLE", "POINT", "NULL", "SUPERELEMENT")


def _netcdf4():
    try:
        import netCDF4
    except ImportError as exc:  # a dependency; only a broken install gets here
        raise SceneError("netCDF4", "is not installed, Exodus II files cannot be read",
                         "pip install netCDF4") from exc
    return netCDF4


def _strings(ds, name: str, rows: int | None, where: str) -> list[str] | None:
    """The names in the char variable ``name`` (``rows`` × length; rows None: its own, at most
    MAX_NAMES), its shape checked before it is read."""
    if name not in ds.variables:
        return None
    shape = tuple(ds.variables[name].shape)
    rows = shape[0] if rows is None and len(shape) == 2 and shape[0] <= MAX_NAMES else rows
    if len(shape) not in (1, 2) or (len(shape) == 2 and shape[0] != rows) or shape[-1] > MAX_NAME_LENGTH:
        raise SceneError(where, f"variable {name!r} has shape {shape}, not ({rows if rows is not None else MAX_NAMES},"
                         f" at most {MAX_NAME_LENGTH})", "write the file again (as an Exodus II writer does)")
    raw = np.asarray(ds.variables[name][:])
    if raw.ndim == 1:
        raw = raw[None]
    return ["".join(c.decode("latin-1") if isinstance(c, bytes) else str(c) for c in row).split("\0")[0].strip()
            for row in raw]


def _dim(ds, name: str, default: int | None = None) -> int:
    if name in ds.dimensions:
        return len(ds.dimensions[name])
    if default is None:
        raise KeyError(name)
    return default


def _variable(ds, name: str, shape: tuple, where: str, dtype=np.float64) -> np.ndarray:
    """Variable ``name`` read as ``dtype``, after its declared shape is checked against ``shape``
    (from the dimensions, which the memory estimate has bounded): nothing larger is read."""
    var = ds.variables[name]
    if math.prod(var.shape) != math.prod(shape):
        raise SceneError(where, f"variable {name!r} has shape {tuple(var.shape)}, where its dimensions give "
                         f"{shape}", "write the file again (as an Exodus II writer does)")
    try:
        return np.asarray(var[:], dtype=dtype).reshape(shape)
    except (RuntimeError, OSError, IndexError) as exc:   # HDF5's errors for a damaged netCDF-4 file
        raise SceneError(where, f"variable {name!r} cannot be read ({exc})", "write or copy the file again") from None


def _check_written(values: np.ndarray, var, name: str, labels: np.ndarray, where: str) -> None:
    """SceneError naming ``name`` if it holds non-finite values or its fill value (never written)."""
    fill = getattr(var, "_FillValue", None)
    fill = float(np.asarray(fill).ravel()[0]) if fill is not None else _NC_FILL_DOUBLE
    bad = ~np.isfinite(values) | (values == fill) | (np.abs(values) >= _NC_FILL_DOUBLE)
    if bad.any():
        rows = np.flatnonzero(bad.reshape(len(labels), -1).any(axis=1))
        value = values.reshape(len(labels), -1)[rows[0]]
        what = "the netCDF fill value (never written)" if np.isfinite(value).all() else "non-finite values"
        raise SceneError(where, f"variable {name!r} holds {what} at {len(rows):,} nodes (first: node "
                         f"{labels[rows[0]]}, {', '.join(f'{x:g}' for x in value)})",
                         "write every node's coordinates as finite numbers")


def element_type(elem_type: str, nodes_per_element: int, where: str, block: str) -> str | None:
    """The meshio cell type of an Exodus ``elem_type`` with that node count; None: ignored."""
    spelled = elem_type.strip().upper()
    m = re.fullmatch(r"([A-Z]+?)(\d*)", spelled)
    family = m.group(1) if m else spelled
    if family in _IGNORED:
        return None
    named = int(m.group(2)) if m and m.group(2) else None
    if named is not None and named != nodes_per_element and named > 4 and family not in _IGNORED:
        raise SceneError(where, f"{block} has {elem_type} elements with {nodes_per_element} nodes each",
                         f"a {elem_type} element needs {named} nodes (a missing node?)")
    if (family, nodes_per_element) in _QUADRATIC:
        return _QUADRATIC[family, nodes_per_element]
    if family in ("WEDGE", "PYRAMID"):
        if nodes_per_element <= 6:   # WEDGE6, PYRAMID5: linear, but glsim extracts no faces of them
            raise SceneError(where, f"{block} has {elem_type} elements ({nodes_per_element} nodes each), which are "
                             "not supported", SOLID_FIX)
        raise SceneError(where, f"{block} has {elem_type} elements ({nodes_per_element} nodes each): " + QUADRATIC_FIX)
    if family in _LINEAR:
        kind, count = _LINEAR[family]
        if nodes_per_element == count:
            return kind
        if nodes_per_element > count:
            raise SceneError(where, f"{block} has {elem_type} elements ({nodes_per_element} nodes each): "
                             + QUADRATIC_FIX)
        raise SceneError(where, f"{block} has {elem_type} elements with {nodes_per_element} nodes each",
                         f"a {family} element needs {count} nodes")
    raise SceneError(where, f"{block} has element type {elem_type!r}, which is not supported", SOLID_FIX)


@contextlib.contextmanager
def open_exodus(path) -> Iterator[Series]:
    """Open an Exodus II file as a :class:`~glsim.io.series.Series` (nodal fields read lazily)."""
    path = Path(path)
    netCDF4 = _netcdf4()
    where = str(path)
    _check_extent(path)
    try:
        ds = netCDF4.Dataset(path, "r")
    except OSError as exc:
        raise SceneError(where, f"is not a netCDF file, so not Exodus II ({exc})",
                         "give an Exodus II result (.e/.exo), e.g. MOOSE's *_out.e") from None
    try:
        ds.set_auto_mask(False)
        yield _series(ds, path)
    finally:
        ds.close()


def _block_label(i: int, names: list[str], ids: list) -> str:
    block_id = ids[i] if i < len(ids) else i + 1
    return f"element block {names[i]!r} (id {block_id})" if i < len(names) and names[i] else f"element block id {block_id}"


def _declared(ds, where: str) -> tuple[int, int, list[int], int]:
    """Nodes, dimensions, elements per block and stored times as the file's dimensions declare
    them, refused (SceneError) where they cannot be, or cannot fit in memory, before any variable
    is read: a netCDF-4 (HDF5) file is not bounded by its length as a classic one is."""
    try:
        n_nodes, n_dim = _dim(ds, "num_nodes"), _dim(ds, "num_dim")
    except KeyError as exc:
        raise SceneError(where, f"has no dimension {exc.args[0]!r}, so is not an Exodus II file "
                         f"(dimensions: {', '.join(ds.dimensions) or 'none'})",
                         "give an Exodus II result (.e/.exo)") from None
    if n_dim not in (2, 3):
        raise SceneError(where, f"declares {n_dim} dimensions (num_dim)", "give 2-D or 3-D nodes")
    n_blocks = _dim(ds, "num_el_blk", 0)
    if n_blocks > len(ds.dimensions):       # each block declares its own num_el_in_blk{i}
        raise SceneError(where, f"declares {n_blocks:,} element blocks (num_el_blk) but has only "
                         f"{len(ds.dimensions)} dimensions", "write or copy the file again")
    counts = [_dim(ds, f"num_el_in_blk{i}", 0) for i in range(1, n_blocks + 1)]
    per_element = sum(c * _dim(ds, f"num_nod_per_el{i}", 0) for i, c in enumerate(counts, 1))
    n_times = _dim(ds, "time_step", 0)
    check_mesh_memory(where, n_nodes, sum(counts), 16 * per_element + 64 * n_times,
                      f" ({n_blocks} element blocks, {n_times:,} stored times)")
    return n_nodes, n_dim, counts, n_times


def _coordinates(ds, n_nodes: int, n_dim: int, labels: np.ndarray, where: str) -> np.ndarray:
    """(n_nodes, n_dim) coordinates; unwritten (fill value) or non-finite ones refused by variable."""
    v = ds.variables
    if "coordx" in v:
        axes = ["coordx", "coordy", "coordz"][:n_dim]
        missing = [a for a in axes if a not in v]
        if missing:
            raise SceneError(where, f"has no coordinate variable {missing[0]!r} for its {n_dim} dimensions",
                             "write coordx, coordy (and coordz in 3-D)")
        columns = [_variable(ds, a, (n_nodes,), where) for a in axes]
        for a, column in zip(axes, columns):
            _check_written(column, v[a], a, labels, where)
        return np.stack(columns, axis=1)
    if "coord" in v:
        coords = _variable(ds, "coord", (n_dim, n_nodes), where)
        _check_written(coords.T, v["coord"], "coord", labels, where)
        return coords.T
    raise SceneError(where, "has no coordinates (neither coordx/coordy/coordz nor coord)",
                     "give an Exodus II file with its nodes")


def _times(ds, n_times: int, where: str) -> np.ndarray:
    """The stored times (time_whole; 0, 1, … without it); a non-finite one refused naming its step."""
    if "time_whole" not in ds.variables:
        return np.arange(n_times, dtype=np.float64)
    var = ds.variables["time_whole"]
    if len(var.shape) != 1 or var.shape[0] < n_times:
        raise SceneError(where, f"variable 'time_whole' has shape {tuple(var.shape)} for {n_times} stored times",
                         "write the file again (as an Exodus II writer does)")
    times = np.asarray(var[:n_times], dtype=np.float64).reshape(-1)
    bad = np.flatnonzero(~np.isfinite(times))
    if len(bad):
        raise SceneError(where, f"time_whole holds {times[bad[0]]} at stored step {bad[0]} ({len(bad)} such steps)",
                         "write finite times (the solver's output was damaged?)")
    return times


def _series(ds, path: Path) -> Series:
    where = str(path)
    n_nodes, n_dim, counts, n_times = _declared(ds, where)
    n_blocks, n_elem = len(counts), sum(counts)
    v = ds.variables
    node_labels = (_variable(ds, "node_num_map", (n_nodes,), where, np.int64) if "node_num_map" in v
                   else np.arange(1, n_nodes + 1))
    points = np.pad(_coordinates(ds, n_nodes, n_dim, node_labels, where), ((0, 0), (0, 3 - n_dim)))
    names = _strings(ds, "eb_names", n_blocks, where) or [""] * n_blocks
    ids = _variable(ds, "eb_prop1", (n_blocks,), where, np.int64).tolist() if "eb_prop1" in v else []
    elem_labels = (_variable(ds, "elem_num_map", (n_elem,), where, np.int64) if "elem_num_map" in v
                   else np.arange(1, n_elem + 1))
    offsets = np.cumsum([0] + counts)
    cells, cell_labels, block_names = [], [], []
    for i, count in enumerate(counts):
        label = _block_label(i, names, ids)
        if count == 0:
            continue
        if f"connect{i + 1}" not in v:
            raise SceneError(where, f"{label} declares {count:,} element{'s' * (count != 1)} (num_el_in_blk{i + 1}) but the file has "
                             f"no connect{i + 1}, so they cannot be read", "write the file again with every "
                             "block's connectivity (a damaged or partly written result?)")
        conn_var = v[f"connect{i + 1}"]
        shape = tuple(conn_var.shape)
        if len(shape) != 2 or shape[0] != count:
            raise SceneError(where, f"{label}: connect{i + 1} has shape {shape} for {count:,} elements",
                             "write the file again (as an Exodus II writer does)")
        kind = element_type(getattr(conn_var, "elem_type", ""), shape[1], where, label)
        if kind is None:
            continue
        conn = _variable(ds, f"connect{i + 1}", shape, where, np.int64)
        if conn.min() < 1 or conn.max() > n_nodes:
            raise SceneError(where, f"{label} refers to nodes {conn.min()}..{conn.max()}, outside 1..{n_nodes}",
                             "connectivity is 1-based node positions")
        if kind in EXODUS_TO_VTK:
            conn = conn[:, EXODUS_TO_VTK[kind]]
        cells.append((kind, conn - 1))
        cell_labels.append(elem_labels[offsets[i]:offsets[i + 1]])
        block_names.append(label)

    times = _times(ds, n_times, where)
    n_vars = _dim(ds, "num_nod_var", 0)
    named = _strings(ds, "name_nod_var", n_vars if "num_nod_var" in ds.dimensions else None, where) or []
    index = {name: j for j, name in enumerate(named) if name}
    fields = {name: 1 for name in index}   # Exodus nodal variables are scalars (disp_x, disp_y, …)

    def read(name: str, k: int) -> np.ndarray:
        j = index[name]
        for var, shape, at in ((f"vals_nod_var{j + 1}", (n_times, n_nodes), (k, slice(None))),
                               ("vals_nod_var", (n_times, n_vars, n_nodes), (k, j, slice(None)))):
            if var not in v:
                continue
            if tuple(v[var].shape) != shape:       # checked before a step is read: nothing larger is
                raise SceneError(where, f"variable {var!r} has shape {tuple(v[var].shape)}, where its "
                                 f"dimensions give {shape}", "write the file again (as an Exodus II writer does)")
            try:
                return np.asarray(v[var][at], dtype=np.float64)
            except (RuntimeError, OSError, IndexError) as exc:   # HDF5's errors for a damaged netCDF-4 file
                raise SceneError(where, f"stored step {k} of nodal variable {name!r} cannot be read ({exc})",
                                 "write or copy the file again") from None
        raise SceneError(where, f"names nodal variable {name!r} but stores no values for it "
                         f"(no vals_nod_var{j + 1} or vals_nod_var)", "write the file with its nodal values")

    return Series(path=path, points=points, dim=n_dim, cells=cells, cell_labels=cell_labels,
                  node_labels=node_labels, times=times, fields=fields, read=read, block_names=block_names)


# ---- classic netCDF: the layout in the header against the file's length --------------------------

_CDF_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 4, 6: 8, 7: 1, 8: 2, 9: 4, 10: 8, 11: 8}   # nc_type → bytes
_STREAMING = 0xFFFFFFFF


def _check_extent(path: Path) -> None:
    """SceneError naming the variable or stored step of a classic netCDF file (CDF-1, -2, -5) that
    lies beyond the end of the file: a truncated file, or a damaged record count."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        if f.read(3) != b"CDF":
            return                                  # netCDF-4 (HDF5), or not netCDF: netCDF4 says
        try:
            numrecs, variables = _classic_layout(f, f.read(1)[0], size)
        except (EOFError, IndexError, ValueError) as exc:
            raise SceneError(str(path), f"its netCDF header is truncated or damaged ({exc})",
                             "write or copy the file again") from None
    records = [(name, begin, n) for name, record, begin, n in variables if record]
    recsize = records[0][2] if len(records) == 1 else sum(-(-n // 4) * 4 for _, _, n in records)
    for name, record, begin, n in variables:
        if not record and begin + n > size:
            raise SceneError(str(path), f"variable {name!r} ends at byte {begin + n:,}, beyond the end of the file "
                             f"({size:,} bytes): the file is truncated", "write or copy the file again")
    if numrecs == _STREAMING or not records:
        return
    inside = {name: 0 if begin + n > size else (size - begin - n) // recsize + 1 if recsize else numrecs
              for name, begin, n in records}       # whole records of each variable inside the file
    name = min(inside, key=inside.get)
    if inside[name] < numrecs:
        raise SceneError(str(path), f"stored step {inside[name]} of the {numrecs:,} its header declares lies beyond "
                         f"the end of the file ({size:,} bytes; variable {name!r} of that step is missing): the file "
                         "is truncated or its record count damaged", "write or copy the file again")


def _classic_layout(f, version: int, size: int) -> tuple[int, list]:
    """The record count and, per variable, (name, is a record variable, begin, bytes per record
    or in all) from a classic netCDF header (after its magic 'CDF')."""
    if version not in (1, 2, 5):
        raise ValueError(f"format version {version}")
    wide = version == 5

    def number(eight: bool = wide) -> int:
        data = f.read(8 if eight else 4)
        if len(data) < (8 if eight else 4):
            raise EOFError("ends inside the header")
        return int.from_bytes(data, "big")

    def count(item_bytes: int) -> int:                  # a list's length, bounded by what the file can hold
        n = number()
        if n * item_bytes > size:
            raise ValueError(f"a list of {n:,} entries in a file of {size:,} bytes")
        return n

    def skip(nbytes: int) -> None:                      # and the padding to 4 bytes
        if f.seek(-(-nbytes // 4) * 4, 1) > size:
            raise EOFError("ends inside the header")

    def name() -> str:
        n = count(1)
        return f.read(-(-n // 4) * 4)[:n].decode("utf-8", "replace")

    def attributes() -> None:
        number(False)
        for _ in range(count(12)):
            name()
            kind = number(False)
            skip(count(_CDF_SIZES[kind]) * _CDF_SIZES[kind])

    numrecs = number()
    number(False)
    dims = [(name(), number()) for _ in range(count(8))]
    attributes()
    number(False)
    variables = []
    for _ in range(count(16)):
        label = name()
        ids = [number() for _ in range(count(4))]
        attributes()
        kind = number(False)
        number()                                        # vsize: recomputed (it overflows for big variables)
        begin = number(version != 1)
        shape = [dims[i][1] for i in ids]
        record = bool(ids) and shape[0] == 0
        variables.append((label, record, begin, math.prod(shape[record:]) * _CDF_SIZES[kind]))
    return numrecs, variables
