"""XDMF files bounded before they are read: every DataItem's declared dimensions against its
source (the XML text, a binary file, an HDF5 dataset's shape read from its metadata) and the
memory budget, the mesh grid's geometry, topology and attributes against each other — before
meshio reads an array. Used by :mod:`glsim.io.series` (time series) and
:mod:`glsim.io.meshfiles` (a single state)."""
from __future__ import annotations

import math
import mmap
import os
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.errors import SceneError


XDMF_FIX = "write the XDMF file and its data again (damaged, or not what it declares)"
_XDMF_TEMPORAL = re.compile(rb"CollectionType=[\"']Temporal[\"']")


def is_temporal_xdmf(path: Path) -> bool:
    """Whether the XDMF file holds a temporal collection, searched in the mapped file (not read whole)."""
    try:
        with open(path, "rb") as f:
            if os.fstat(f.fileno()).st_size == 0:
                return False
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
                return _XDMF_TEMPORAL.search(mm) is not None
    except (OSError, ValueError):
        return False


@dataclass(frozen=True)
class DataItem:
    """What one XDMF DataItem declares: where it is (for messages), its Dimensions and the bytes the
    array it names is read into (HDF5: the dataset's shape, which meshio reads whatever the
    Dimensions say)."""
    where: str
    dims: tuple[int, ...]
    nbytes: int


def _xdmf_source(path: Path, where: str, item, dims: tuple[int, ...], itemsize: int) -> int:
    """Bytes the array of ``item`` (Format XML, Binary or HDF) is read into, refused (SceneError)
    where its text, file or HDF5 dataset cannot hold the Dimensions or disagrees with them."""
    from glsim.limits import not_a_file

    n = math.prod(dims)
    text = (item.text or "").strip()
    fmt = item.get("Format")
    if fmt == "XML":
        if n > (len(text) + 1) // 2:
            raise SceneError(str(path), f"{where} declares Dimensions {_dims(dims)} ({n:,} values), more "
                             f"than its {len(text):,} characters of text can hold", XDMF_FIX)
        return n * itemsize
    if fmt == "Binary":                                  # meshio opens the name as given, reads it whole
        why = not_a_file(text)
        if why:
            raise SceneError(str(path), f"{where} names the binary file {text}, which {why.removeprefix('is ')}",
                             "keep the data file beside the XDMF file")
        size = os.stat(text).st_size
        if size != n * itemsize:
            raise SceneError(str(path), f"{where} declares Dimensions {_dims(dims)} ({n:,} values of "
                             f"{itemsize} bytes), but {text} holds {size:,} bytes", XDMF_FIX)
        return size
    if fmt != "HDF" or text.count(":") != 1:
        return 0                                         # meshio names it
    name, inside = text.split(":")
    h5 = path.resolve().parent / name
    why = not_a_file(h5)
    if why:
        raise SceneError(str(path), f"{where} names {h5}, which {why.removeprefix('is ')}",
                         "keep the .h5 file beside the XDMF file")
    import h5py
    try:
        with h5py.File(h5, "r") as f:
            node = f
            for key in inside.strip("/").split("/"):
                node = node[key]
            shape, size = tuple(int(s) for s in node.shape), node.dtype.itemsize
    except (OSError, KeyError, AttributeError, TypeError, ValueError):
        return 0                                         # not a dataset: meshio names it
    if math.prod(shape) != n:
        raise SceneError(str(path), f"{where} declares Dimensions {_dims(dims)} ({n:,} values), but "
                         f"{name}:{inside} holds {shape} ({math.prod(shape):,} values)", XDMF_FIX)
    return math.prod(shape) * size


def _xdmf_item(path: Path, where: str, element, seen: set | None = None) -> DataItem | None:
    """The DataItem of the XDMF element ``element`` (a Geometry, Topology or Attribute), or the
    DataItem ``element`` itself, bounded against its source and the memory budget; None where
    meshio cannot read it either (it names why) or where it refers to another (bounded on its own).
    ``seen``: the ids of the DataItems bounded so far, this one added."""
    from meshio.xdmf.common import xdmf_to_numpy_type

    from glsim.limits import check_need

    item = element if element.tag == "DataItem" else element.find("DataItem")
    if item is None or "Reference" in item.attrib:
        return None
    if seen is not None:
        seen.add(id(item))
    try:
        dims = tuple(int(d) for d in item.get("Dimensions", "").split())
        kind = item.get("DataType") or item.get("NumberType") or "Float"
        itemsize = np.dtype(xdmf_to_numpy_type[(kind, item.get("Precision", "4"))]).itemsize
    except (ValueError, KeyError):
        return None
    if not dims or min(dims) < 0:
        raise SceneError(str(path), f"{where} declares Dimensions {item.get('Dimensions')!r}",
                         "give positive Dimensions")
    n = math.prod(dims)
    check_need(str(path), n * itemsize, f"{where} declares Dimensions {_dims(dims)} ({n:,} values of "
               f"{itemsize} bytes), which need", "give a coarser mesh, or run on a machine with more memory")
    return DataItem(where, dims, _xdmf_source(path, where, item, dims, itemsize))


def _xdmf_mesh_grid(domain, collection):
    """The grid meshio's TimeSeriesReader takes the mesh from (the last uniform grid of the domain,
    else the first of the collection)."""
    uniform = [g for g in domain if g.get("GridType") == "Uniform"]
    if uniform:
        return uniform[-1]
    return next((g for g in collection if g.get("GridType") == "Uniform"), None)


def check_xdmf(path: Path) -> None:
    """SceneError naming the DataItem (its grid, Geometry, Topology or Attribute) where an XDMF file
    declares what cannot be true or cannot fit, checked before meshio reads any array: each
    DataItem's Dimensions against the memory budget and against its source (XML text, binary
    file, or the HDF5 dataset's shape, read from its metadata), the nodes and elements against the
    mesh estimate (:func:`~glsim.limits.check_mesh_memory`, with the largest time step's
    attributes), and each Attribute's first dimension against the node (Center="Node") or
    element (Center="Cell") count. The XML itself is read only where its length fits the memory
    estimate of a text mesh file. What meshio cannot read either is left to it."""
    from glsim.limits import MESH_BYTES_PER_TEXT_BYTE, MESH_FIX, check_need

    size = path.stat().st_size
    check_need(str(path), size * MESH_BYTES_PER_TEXT_BYTE, f"its {size:,} bytes of XML need", MESH_FIX)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError):
        return
    seen: set[int] = set()
    _check_xdmf_mesh(path, root, seen)
    for k, item in enumerate(root.iter("DataItem")):    # the others, wherever they are (a Reference may name one)
        if id(item) not in seen:
            _xdmf_item(path, f"DataItem {k + 1}" + (f" {item.get('Name')!r}" if item.get("Name") else ""), item)


def _check_xdmf_mesh(path: Path, root, seen: set) -> None:
    """:func:`check_xdmf`'s checks of the mesh grid meshio reads and of the attributes of each step."""
    from meshio._common import num_nodes_per_cell
    from meshio.xdmf.common import xdmf_to_meshio_type

    from glsim.limits import check_mesh_memory

    domain = root.find("Domain")
    if domain is None:
        return
    collections = [g for g in domain if g.tag == "Grid" and g.get("GridType") == "Collection"]
    collection = list(collections[-1]) if collections else None
    grid = _xdmf_mesh_grid(domain, collection) if collection is not None else domain.find("Grid")
    if grid is None:
        return
    name = f"Grid {grid.get('Name')!r}" if grid.get("Name") else "its mesh Grid"
    points = [_xdmf_item(path, f"{name}: Geometry", g, seen) for g in grid.findall("Geometry")]
    found = grid.findall("Topology")
    topologies = [(t, _xdmf_item(path, f"{name}: Topology" + f" {k + 1}" * (len(found) > 1), t, seen))
                  for k, t in enumerate(found)]
    if not points or points[-1] is None or not topologies or any(c is None for _, c in topologies):
        return
    points = points[-1]                                  # meshio keeps the last
    if len(points.dims) != 2 or points.dims[1] not in (2, 3):
        raise SceneError(str(path), f"{points.where} declares Dimensions {_dims(points.dims)}, not (nodes, 2 or 3)",
                         XDMF_FIX)
    n_nodes, n_cells, mixed = points.dims[0], 0, False
    for topology, cells in topologies:
        kind = topology.get("Type") or topology.get("TopologyType")
        mixed |= kind == "Mixed"
        n_cells += cells.dims[0] if kind != "Mixed" else math.prod(cells.dims)   # Mixed: at most one a value
        corners = num_nodes_per_cell.get(xdmf_to_meshio_type.get(kind, ""))
        if corners and kind != "Mixed" and math.prod(cells.dims[1:]) != corners:
            raise SceneError(str(path), f"{cells.where} ({kind}) declares Dimensions {_dims(cells.dims)}, not "
                             f"({cells.dims[0]}, {corners})", XDMF_FIX)
    counts = {"Node": (n_nodes, "nodes", points.where),
              "Cell": (n_cells, "elements", f"{name}: Topology") if not mixed else None}
    largest = 0
    for k, step in enumerate([grid] if collection is None else collection):
        step_bytes = 0
        for attribute in step.findall("Attribute"):
            where = (f"time step {k}, " if collection is not None else "") + f"Attribute {attribute.get('Name')!r}"
            item = _xdmf_item(path, where, attribute, seen)
            if item is None:
                continue
            center = attribute.get("Center")
            count = counts.get(center)
            if count is not None and item.dims[0] != count[0]:
                raise SceneError(str(path), f"{where} (Center {center!r}) declares Dimensions {_dims(item.dims)}, but "
                                 f"the mesh has {count[0]:,} {count[1]} ({count[2]})", XDMF_FIX)
            step_bytes += item.nbytes
        largest = max(largest, step_bytes)
    check_mesh_memory(str(path), n_nodes, n_cells, points.nbytes + sum(c.nbytes for _, c in topologies) + largest,
                      " (its Geometry and Topology DataItems)")


def _dims(dims: tuple[int, ...]) -> str:
    return "'" + " ".join(map(str, dims)) + "'"


# --- XDMF time series -------------------------------------------------------------------
