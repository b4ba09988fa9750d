"""FE mesh files → :class:`~glsim.scene.mesh.Mesh`, read with meshio (Abaqus ``.inp``, VTK/VTU,
Gmsh, …): Q4 quads, T3 triangles (collapsed quads), the outer faces of hex8/tet4 solids, and
per-step displacements from point data, one file per step, or ``label;ux;uy;uz`` CSV files.
Quadratic elements (quad8, quad9, triangle6 shells; the outer faces of hexahedron20,
hexahedron27, tetra10, wedge15 solids) become 9-node patches (``Mesh.patches``,
:mod:`glsim.scene.quadratic`); a file mixing linear and quadratic elements is refused. What a
file declares is bounded before meshio allocates it (:func:`check_mesh_file`)."""
from __future__ import annotations

import contextlib
import io
import json
import mmap
import re
from pathlib import Path
from typing import Sequence

import meshio
import numpy as np

from glsim.errors import SceneError
from glsim.limits import (MAX_INCLUDE_DEPTH, MESH_BYTES_PER_TEXT_BYTE, MESH_FIX, check_mesh_memory, check_need,
                          not_a_file, require_file)
from glsim.scene import quadratic as qd
from glsim.scene.mesh import Mesh, check_finite, place_mesh, quad_normals, with_displacements

SOLID_FIX = ("use quad/triangle shells (linear or quad8/quad9/triangle6) or hexahedron/tetra solids (linear, or "
             "hexahedron20/27, tetra10, wedge15); their outer faces are rendered")

# Faces of meshio's (VTK/Abaqus-ordered) solids, counter-clockwise seen from outside.
_SOLID_FACES = {
    "hexahedron": np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4],
                            [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]),
    "tetra": np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]),
}
_IGNORED_CELLS = ("line", "vertex", "line3")

# Quadratic cells (meshio's node order, which is VTK's) → rows of 9-node patches. A row lists
# the cell's local node per patch node; Q8 / T6 mark a derived centre (glsim.scene.quadratic).
Q8, T6 = qd.CENTRE_Q8, qd.CENTRE_T6
_QUADRATIC_SHELLS = {"quad8": [[0, 1, 2, 3, 4, 5, 6, 7, Q8]], "quad9": [list(range(9))],
                     "triangle6": [[0, 1, 2, 2, 3, 4, 2, 5, T6]]}


def _face_rows(faces, edges, centres=None):
    """Patch rows of a solid's faces: corner cycles (CCW from outside) → corners, the mid-edge
    nodes from ``edges`` {(i, j): node}, and the face centre (``centres``) or a derived one."""
    mid = {frozenset(k): v for k, v in edges.items()}
    rows = []
    for f, face in enumerate(faces):
        if len(face) == 3:
            a, b, c = face
            rows.append([a, b, c, c, mid[frozenset((a, b))], mid[frozenset((b, c))], c, mid[frozenset((c, a))], T6])
        else:
            ring = [mid[frozenset((face[k], face[(k + 1) % 4]))] for k in range(4)]
            rows.append(list(face) + ring + [centres[f] if centres is not None else Q8])
    return rows


_HEX_FACES = [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]]
_HEX_EDGES = {(0, 1): 8, (1, 2): 9, (2, 3): 10, (3, 0): 11, (4, 5): 12, (5, 6): 13, (6, 7): 14, (7, 4): 15,
              (0, 4): 16, (1, 5): 17, (2, 6): 18, (3, 7): 19}
# VTK_TRIQUADRATIC_HEXAHEDRON's face centres: 20 x-min, 21 x-max, 22 y-min, 23 y-max, 24 z-min,
# 25 z-max (the order meshio's Gmsh reader converts to), listed here per _HEX_FACES entry
_HEX27_CENTRES = [24, 25, 22, 21, 23, 20]
_TET_FACES = [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]
_TET_EDGES = {(0, 1): 4, (1, 2): 5, (0, 2): 6, (0, 3): 7, (1, 3): 8, (2, 3): 9}
_WEDGE_FACES = [[0, 2, 1], [3, 4, 5], [0, 1, 4, 3], [1, 2, 5, 4], [2, 0, 3, 5]]
_WEDGE_EDGES = {(0, 1): 6, (1, 2): 7, (2, 0): 8, (3, 4): 9, (4, 5): 10, (5, 3): 11, (0, 3): 12, (1, 4): 13,
                (2, 5): 14}
_QUADRATIC_SOLIDS = {"hexahedron20": _face_rows(_HEX_FACES, _HEX_EDGES),
                     "hexahedron27": _face_rows(_HEX_FACES, _HEX_EDGES, _HEX27_CENTRES),
                     "tetra10": _face_rows(_TET_FACES, _TET_EDGES),
                     "wedge15": _face_rows(_WEDGE_FACES, _WEDGE_EDGES)}
_NODES_PER_CELL = {"quad8": 8, "quad9": 9, "triangle6": 6, "hexahedron20": 20, "hexahedron27": 27, "tetra10": 10,
                   "wedge15": 15}
QUADRATIC_CELLS = tuple(_NODES_PER_CELL)

# ---- what a mesh file declares, bounded before meshio allocates it ----------------------------------

def check_mesh_file(path: Path, roots: Sequence[Path] = ()) -> None:
    """SceneError naming the file (or the culprit in it) if the counts a mesh file declares cannot be
    true of its length or cannot fit in memory (:func:`~glsim.limits.check_mesh_memory`), read from its
    headers before meshio allocates them: Gmsh's sections and each of their blocks (:func:`glsim.io.gmshcheck.check_gmsh`),
    legacy VTK's POINTS/CELLS, a VTU's pieces and data-array headers (:func:`glsim.io.vtkfiles.check_vtu`),
    an XDMF file's DataItems (:func:`glsim.io.xdmfcheck.check_xdmf`); an Abaqus file's text with its
    ``*INCLUDE`` files, which must be regular files inside ``roots`` or the file's own folder. A
    header that cannot be read is left to meshio, which names the problem."""
    suffix = path.suffix.lower()
    if suffix == ".inp":
        total = _abaqus_bytes(path, [path.parent.resolve(), *(Path(r).resolve() for r in roots)], [])
        check_need(str(path), total * MESH_BYTES_PER_TEXT_BYTE, f"its {total:,} bytes of text (with its "
                   "*INCLUDE files) need", MESH_FIX)
    elif suffix == ".msh":
        from glsim.io.gmshcheck import check_gmsh
        check_gmsh(path)
    elif suffix == ".vtk":
        _check_legacy_vtk(path)
    elif suffix == ".vtu":
        from glsim.io.vtkfiles import check_vtu
        check_vtu(path)
    elif suffix in (".xdmf", ".xmf"):
        from glsim.io.xdmfcheck import check_xdmf
        check_xdmf(path)


def _abaqus_bytes(path: Path, roots: list[Path], chain: list[Path]) -> int:
    """Bytes of the Abaqus file ``path`` and of the files it includes (``*INCLUDE, INPUT=``), each
    resolved as meshio resolves it (the working directory first, then the including file's folder)
    and refused (SceneError) unless a regular file inside ``roots``, at most MAX_INCLUDE_DEPTH deep,
    not including itself."""
    total = path.stat().st_size
    check_need(str(path), total * MESH_BYTES_PER_TEXT_BYTE, f"its {total:,} bytes of text need", MESH_FIX)
    with _text(path) as f:
        lines = [line for line in f if line.startswith("*") and not line.startswith("**")
                 and line.partition(",")[0].strip().replace("*", "").upper() == "INCLUDE"]
    for line in lines:
        name = line.split("=")[-1].strip()
        where = f"{path}: *INCLUDE, INPUT={name}"
        target = Path(name) if Path(name).exists() else path.parent / name
        why = not_a_file(target)
        if why:
            raise SceneError(where, f"{target} {why}", "include a regular file beside the mesh file")
        real = target.resolve()
        if not any(real.is_relative_to(root) for root in roots):
            raise SceneError(where, f"{real} lies outside the mesh and scene folders (not read)",
                             "keep included files in the mesh file's folder")
        if real in chain or len(chain) >= MAX_INCLUDE_DEPTH:
            raise SceneError(where, f"includes nest more than {MAX_INCLUDE_DEPTH} deep or include themselves "
                             f"({' → '.join(p.name for p in [*chain, real])})", "include each file once")
        total += _abaqus_bytes(target, roots, [*chain, real])
    return total


# legacy VTK: a count keyword, its count, and the fewest bytes one counted item takes (ASCII or binary)
_VTK_COUNTS = re.compile(rb"(?:^|\n)[ \t]*(POINTS|CELLS|CELL_TYPES|POINT_DATA|CELL_DATA)"
                         rb"[ \t]+(-?\d+)(?:[ \t]+(-?\d+))?")


def _check_legacy_vtk(path: Path) -> None:
    """Legacy VTK's declared counts (POINTS, CELLS, …) against the file's length (each item takes at
    least 2 bytes of text, or 4 of binary) and the memory estimate, before meshio allocates them."""
    size = path.stat().st_size
    if size == 0:
        return
    with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        binary = b"\nBINARY" in mm[:1024].upper()
        declared = {}
        for m in _VTK_COUNTS.finditer(mm):
            keyword, n = m.group(1).decode(), int(m.group(2))
            items = max(n, int(m.group(3) or 0)) * (3 if keyword == "POINTS" else 1)   # CELLS n size: size ints
            if n < 0 or items * (4 if binary else 2) > size:
                raise SceneError(str(path), f"{keyword} declares {n:,} items, more than its {size:,} bytes can hold",
                                 "write or export the file again (damaged or truncated?)")
            declared.setdefault(keyword, n)
    check_mesh_memory(str(path), declared.get("POINTS", 0), declared.get("CELLS", declared.get("CELL_TYPES", 0)),
                      what=" (its POINTS and CELLS)")


def require_input_file(path) -> Path:
    return require_file(path, str(path), "check the path (relative paths start at the working directory)")


def meshio_read(path, roots: Sequence[Path] = ()):
    """``meshio.read``, after :func:`check_mesh_file` has bounded what the file declares; its
    printed messages captured: for a file it cannot read it prints why and calls ``sys.exit``,
    which here raises meshio.ReadError with those words instead. ``roots``: the folders an Abaqus
    ``*INCLUDE`` may read from besides the file's own."""
    check_mesh_file(Path(path), roots)
    said = io.StringIO()
    try:
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            return meshio.read(path)
    except SystemExit:
        lines = [line.strip().removeprefix("Error: ") for line in said.getvalue().splitlines()]
        raise meshio.ReadError("; ".join(filter(None, lines)) or "meshio gave up") from None


def _read_meshio(path, roots: Sequence[Path] = ()):
    path = require_input_file(path)
    try:
        raw = meshio_read(path, roots)
    except SceneError:
        raise
    except Exception as exc:  # meshio's readers raise many types; wrap their words once
        if isinstance(exc, KeyError) and "wedge15" in str(exc):
            raise SceneError(str(path), "meshio cannot read its wedge15 cells (meshio 5.3's table of cell "
                             "dimensions lacks them)", "export the solid as hexahedron20 or tetra10, or "
                             "upgrade meshio") from exc
        raise SceneError(str(path), f"meshio could not read it ({type(exc).__name__}: {exc})",
                         "give an Abaqus .inp, VTK .vtk/.vtu or Gmsh .msh file") from exc
    if np.ndim(raw.points) != 2 or not len(raw.points):
        raise SceneError(str(path), "holds no nodes (an empty or truncated file?)", "give the FE mesh file")
    return raw


def as_xyz(points) -> np.ndarray:
    """(N,2) or (N,3) → (N,3) with z = 0 for 2-D data."""
    points = np.asarray(points, dtype=np.float64)
    return np.pad(points, ((0, 0), (0, 3 - points.shape[1])))


def _abaqus_labels(path: Path) -> tuple[list[int], list[list[int]]]:
    """*NODE labels and, per *ELEMENT block, its integers, split the way meshio reads them.

    meshio re-indexes Abaqus nodes and elements and drops their labels.
    """
    nodes: list[int] = []
    elements: list[list[int]] = []
    block = None
    with _text(path) as f:
        for line in f:
            if line.startswith("*"):  # keyword or ** comment: both end a data block in meshio
                keyword = line.partition(",")[0].strip().replace("*", "").upper()
                block = keyword if not line.startswith("**") and keyword in ("NODE", "ELEMENT") else None
                if block == "ELEMENT":
                    elements.append([])
            elif line.strip() and block in ("NODE", "ELEMENT"):
                try:
                    numbers = [int(k) for k in line.split(",")[:1 if block == "NODE" else None] if k.strip()]
                except ValueError:
                    raise SceneError(str(path), f"*{block} line {line.strip()[:60]!r} does not start with integer "
                                     "labels", "write one node or element per line: label, …") from None
                (nodes if block == "NODE" else elements[-1]).extend(numbers)
    return nodes, elements


@contextlib.contextmanager
def _text(path: Path):
    """``path`` opened as UTF-8 text; bytes that are not (a latin-1 file) raise SceneError naming it."""
    try:
        with open(path, encoding="utf-8") as f:
            yield f
    except UnicodeDecodeError as exc:
        raise SceneError(str(path), f"is not UTF-8 text (it holds the byte 0x{exc.object[exc.start]:02x}: latin-1?)",
                         "save it as UTF-8 or ASCII") from None


def _labels(path: Path, raw) -> tuple[np.ndarray, list[np.ndarray]]:
    """Node labels (N,) and per-cell-block element labels of a meshio mesh read from `path`."""
    n = len(raw.points)
    ordinals = np.cumsum([0] + [len(b.data) for b in raw.cells]) + 1
    element_labels = [np.arange(ordinals[i], ordinals[i + 1]) for i in range(len(raw.cells))]
    if path.suffix.lower() != ".inp":
        for name in ("node_id", "label"):
            if name in raw.point_data and np.size(raw.point_data[name]) == n:
                return np.asarray(raw.point_data[name]).reshape(n).astype(np.int64), element_labels
        return np.arange(1, n + 1), element_labels
    nodes, elements = _abaqus_labels(path)
    if len(nodes) != n:
        raise SceneError(str(path), f"found {len(nodes)} *NODE labels for meshio's {n} nodes",
                         "put all nodes in one *NODE block of this file (no *INCLUDE)")
    if len(elements) == len(raw.cells) and all(len(e) == b.data.size + len(b.data)
                                               for e, b in zip(elements, raw.cells)):
        element_labels = [np.reshape(e, (len(b.data), -1))[:, 0] for e, b in zip(elements, raw.cells)]
    return np.asarray(nodes, dtype=np.int64), element_labels


def _boundary_faces(cells: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces (F,k) of `cells` that belong to exactly one cell, and each face's parent cell index."""
    all_faces = cells[:, faces].reshape(-1, faces.shape[1])
    parent = np.repeat(np.arange(len(cells)), len(faces))
    _, inverse, counts = np.unique(np.sort(all_faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    return all_faces[once], parent[once]


def _collapse(triangles: np.ndarray) -> np.ndarray:
    """Triangles (a, b, c) → collapsed quads (a, b, c, c)."""
    return np.concatenate([triangles, triangles[:, 2:]], axis=1)


def _outward(nodes: np.ndarray, quads: np.ndarray, parent_centroids: np.ndarray) -> np.ndarray:
    """Reverse the quads whose normal points towards their parent solid (mirrored node order).

    (a, b, c, d) → (b, a, d, c) reverses the cycle and keeps a collapsed node pair last.
    """
    inward = np.einsum("ij,ij->i", quad_normals(nodes, quads), nodes[quads].mean(axis=1) - parent_centroids) < 0
    return np.where(inward[:, None], quads[:, [1, 0, 3, 2]], quads)


def _patch_rows(cells: np.ndarray, rows) -> np.ndarray:
    """Patch rows (C·F, 9) of ``cells`` (C, k) for the templates ``rows`` (F, 9) (codes kept)."""
    T = np.asarray(rows)
    out = cells[:, np.maximum(T, 0)]
    return np.where(T < 0, T, out).reshape(-1, 9)


def _outward_patches(nodes: np.ndarray, patches: np.ndarray, parent_centroids: np.ndarray) -> np.ndarray:
    """The quadratic twin of :func:`_outward`: mirror (ξ → −ξ) the patches facing their solid."""
    quads = patches[:, :4]
    inward = np.einsum("ij,ij->i", quad_normals(nodes, quads), nodes[quads].mean(axis=1) - parent_centroids) < 0
    return np.where(inward[:, None], patches[:, qd.REVERSED], patches)


def _quadratic_block(path: Path, kind: str, cells: np.ndarray, nodes: np.ndarray, name: str):
    """Patches (F, 9) of one quadratic cell block and the cell of each."""
    if cells.ndim != 2 or cells.shape[1] != _NODES_PER_CELL[kind]:
        raise SceneError(str(path), f"{name}: {kind} elements with {cells.shape[-1]} nodes each, not "
                         f"{_NODES_PER_CELL[kind]} (a missing node?)", f"give every {kind} element all its nodes")
    if kind in _QUADRATIC_SHELLS:
        return _patch_rows(cells, _QUADRATIC_SHELLS[kind]), np.arange(len(cells))
    rows = _patch_rows(cells, _QUADRATIC_SOLIDS[kind])
    nf = len(_QUADRATIC_SOLIDS[kind])
    parent = np.repeat(np.arange(len(cells)), nf)
    # a face is on the boundary when no other cell has the same corners
    _, inverse, counts = np.unique(np.sort(rows[:, :4], axis=1), axis=0, return_inverse=True, return_counts=True)
    once = counts[inverse.ravel()] == 1
    rows, parent = rows[once], parent[once]
    corners = {"hexahedron20": 8, "hexahedron27": 8, "tetra10": 4, "wedge15": 6}[kind]
    return _outward_patches(nodes, rows, nodes[cells[parent, :corners]].mean(axis=1)), parent


def check_node_range(path: Path, cells: np.ndarray, n: int, kind: str, labels: np.ndarray) -> None:
    """SceneError naming the first element of ``cells`` that refers to a node outside the file's ``n``
    (checked before any face or centroid is indexed)."""
    if cells.size == 0:
        return
    bad = np.flatnonzero(((cells < 0) | (cells >= n)).reshape(len(cells), -1).any(axis=1))
    if len(bad):
        row = cells[bad[0]]
        label = labels[bad[0]] if bad[0] < len(labels) else bad[0] + 1
        raise SceneError(str(path), f"{kind} element {label} refers to node {row[(row < 0) | (row >= n)][0] + 1} "
                         f"(1-based position), outside the file's {n:,} nodes ({len(bad):,} such elements)",
                         "give every element's nodes from the file's node list")


def surface_from_cells(path: Path, raw, nodes: np.ndarray, element_labels: list[np.ndarray]):
    """Surface quads (M,4), their element labels and, for quadratic elements, the 9-node
    patches (M,9) (else None) from meshio's cell blocks."""
    quads, labels, patches = [], [], []
    linear, quadratic = [], []
    for k, (block, block_labels) in enumerate(zip(raw.cells, element_labels)):
        cells = np.asarray(block.data, dtype=np.int64)
        check_node_range(path, cells, len(nodes), block.type, block_labels)
        if block.type in QUADRATIC_CELLS:
            rows, parent = _quadratic_block(path, block.type, cells, nodes, f"cell block {k + 1}")
            patches.append(rows)
            quads.append(rows[:, :4])
            labels.append(block_labels[parent])
            quadratic.append(block.type)
            continue
        if block.type == "quad":
            quads.append(cells)
            labels.append(block_labels)
        elif block.type == "triangle":
            quads.append(_collapse(cells))
            labels.append(block_labels)
        elif block.type in _SOLID_FACES:
            faces, parent = _boundary_faces(cells, _SOLID_FACES[block.type])
            faces = _collapse(faces) if faces.shape[1] == 3 else faces
            quads.append(_outward(nodes, faces, nodes[cells[parent]].mean(axis=1)))
            labels.append(block_labels[parent])
        elif block.type not in _IGNORED_CELLS:
            raise SceneError(str(path), f"element type '{block.type}' is not supported", SOLID_FIX)
        else:
            continue
        linear.append(block.type)
    if linear and quadratic:
        raise SceneError(str(path), f"mixes linear ({', '.join(sorted(set(linear)))}) and quadratic "
                         f"({', '.join(sorted(set(quadratic)))}) elements",
                         "export the whole specimen surface at one element order")
    if not quads or sum(map(len, quads)) == 0:
        raise SceneError(str(path), "has no quad, triangle, hexahedron or tetra elements", SOLID_FIX)
    return np.concatenate(quads), np.concatenate(labels), (np.concatenate(patches) if quadratic else None)


def _vector_field(array, n: int, key: str, name: str, step: int, node_labels: np.ndarray) -> np.ndarray:
    """Point-data array ``name`` → the (N,3) displacement of load ``step``; 2-component or
    otherwise shaped arrays and non-finite values raise SceneError naming the array."""
    array = np.asarray(array, dtype=np.float64)
    if array.ndim == 2 and array.shape == (n, 2):
        raise SceneError(key, f"point-data array {name!r} (load step {step}) has 2 components per node, "
                         "not 3 (ux, uy, uz)", "write the displacement with 3 components (uz = 0 for a "
                         "plane field); glsim does not guess which plane 2 components lie in")
    if array.ndim != 2 or array.shape != (n, 3):
        raise SceneError(key, f"point-data array {name!r} (load step {step}) has shape {array.shape}, "
                         f"not ({n}, 3)", "give a displacement vector (ux, uy, uz) per node")
    check_finite(array, node_labels, key, f"point-data array {name!r} (load step {step})")
    return array


def _point_data_steps(path: Path, raw, names: Sequence[str], node_labels: np.ndarray) -> list[np.ndarray]:
    steps = []
    for i, name in enumerate(names):
        if name not in raw.point_data:
            have = list(raw.point_data)
            raise SceneError(str(path), f"has no point-data array {name!r} (point_data[{i}], load step {i + 1}); "
                             f"it has: {', '.join(have) or 'none'}",
                             "set specimen.mesh.point_data to names from that list, one array per load step "
                             f"after the reference, e.g. {json.dumps(have[:3] or ['u1', 'u2', 'u3'])}")
        steps.append(_vector_field(raw.point_data[name], len(raw.points), str(path), name, i + 1, node_labels))
    return steps


def _file_step(path, n: int, field: str | None, step: int, node_labels: np.ndarray) -> np.ndarray:
    """Displacement (N,3) from the point data of a mesh file with the same nodes in the same order."""
    raw = _read_meshio(path)
    key = str(path)
    if len(raw.points) != n:
        raise SceneError(key, f"has {len(raw.points)} nodes, the mesh has {n}",
                         "give one file per step on the same mesh (same nodes, same order)")
    if field is None:
        vectors = [k for k, v in raw.point_data.items() if np.shape(v) == (n, 3)]
        if len(vectors) != 1:
            raise SceneError(key, f"found {len(vectors)} 3-vector point-data arrays ({', '.join(vectors) or 'none'})",
                             "set field (specimen.mesh.field) to the displacement array's name")
        field = vectors[0]
    if field not in raw.point_data:
        raise SceneError(key, f"no point-data array {field!r} (has: {', '.join(raw.point_data) or 'none'})",
                         "set field (specimen.mesh.field) to a name from that list")
    return _vector_field(raw.point_data[field], n, key, field, step, node_labels)


def _csv_step(path, node_labels: np.ndarray, step: int = 1) -> np.ndarray:
    """Displacement (N,3) from a CSV of `label;ux;uy;uz` lines (',' also accepted, one header line allowed)."""
    path = require_input_file(path)
    index = {int(label): i for i, label in enumerate(node_labels)}
    u = np.zeros((len(node_labels), 3))
    given = np.zeros(len(node_labels), dtype=bool)
    bad: list = []          # (line, label, values) of non-finite displacements
    seen_data = False
    with _text(path) as f:
        for lineno, line in enumerate(f, 1):
            text = line.strip()
            if not text:
                continue
            parts = text.split(";" if ";" in text else ",")
            try:
                label, values = int(parts[0]), [float(p) for p in parts[1:]]
            except ValueError:
                if not seen_data:  # the header line
                    seen_data = True
                    continue
                raise SceneError(f"{path}:{lineno}", f"{text!r} is not numeric",
                                 "write lines 'label;ux;uy;uz' with an integer label and numbers") from None
            seen_data = True
            if len(values) != 3:
                raise SceneError(f"{path}:{lineno}", f"{len(parts)} fields instead of 4", "write 'label;ux;uy;uz'")
            if label not in index:
                raise SceneError(f"{path}:{lineno}", f"node label {label} is not in the mesh",
                                 "use the mesh file's node labels")
            if given[index[label]]:
                raise SceneError(f"{path}:{lineno}", f"node label {label} appears twice", "give one line per node")
            if not np.isfinite(values).all():
                bad.append((lineno, label, values))
            u[index[label]], given[index[label]] = values, True
    missing = np.flatnonzero(~given)
    if len(missing):
        first = ", ".join(str(label) for label in node_labels[missing[:5]])
        raise SceneError(str(path), f"{len(missing)} mesh nodes have no displacement (labels {first}"
                         f"{', …' if len(missing) > 5 else ''})", "give one line per mesh node")
    if bad:
        lineno, label, values = bad[0]
        raise SceneError(f"{path}:{lineno}", f"load step {step}: non-finite (NaN or inf) displacement {values} of "
                         f"node label {label} ({len(bad)} such lines in the file)", "give finite numbers for every node")
    return u


def read_mesh_file(path, unit: str = "mm", R=None, t=None, point_data_steps: Sequence[str] | None = None,
              displacement_files: Sequence | None = None, csv_files: Sequence | None = None,
              field: str | None = None, roots: Sequence = ()) -> Mesh:
    """Read a mesh file (Abaqus .inp, VTK .vtk/.vtu, Gmsh .msh, … via meshio) as a world-frame Mesh.

    quad → Q4; triangle → collapsed Q4; hexahedron / tetra → their outer faces, CCW seen
    from outside; line/vertex cells are ignored. Node labels: Abaqus *NODE labels, else
    point data "node_id"/"label", else 1..N; element labels: Abaqus labels (boundary faces
    get their solid's), else the 1-based position in the file.

    Load steps 1..n come from at most one of: point_data_steps (point-data names in this
    file), displacement_files (one mesh file per step, point data `field`, default the only
    3-vector array) or csv_files (one `label;ux;uy;uz` file per step). Each step's
    displacement is the total from the reference (step 0), not an increment, with 3
    components per node (2-component arrays are refused). Coordinates and displacements are
    in `unit`, then placed by place(…, unit, R, t). An Abaqus ``*INCLUDE`` is read only from the
    file's own folder or ``roots`` (the scene's folder). Single-state files only: use
    :func:`glsim.io.fe.load_mesh`, which also reads time series.
    """
    sources = [s for s in (point_data_steps, displacement_files, csv_files) if s is not None]
    if len(sources) > 1:
        raise SceneError("specimen", "more than one displacement source given",
                         "use only one of point_data_steps, displacement_files, csv_files")
    raw = _read_meshio(path, [Path(r) for r in roots])
    path = Path(path)
    nodes = as_xyz(raw.points)
    node_labels, element_labels = _labels(path, raw)
    quads, labels, patches = surface_from_cells(path, raw, nodes, element_labels)
    if point_data_steps is not None:
        steps = _point_data_steps(path, raw, point_data_steps, node_labels)
    elif displacement_files is not None:
        steps = [_file_step(p, len(nodes), field, k, node_labels) for k, p in enumerate(displacement_files, 1)]
    else:
        steps = [_csv_step(p, node_labels, k) for k, p in enumerate(csv_files or (), 1)]
    try:
        mesh = with_displacements(Mesh(nodes, quads, node_labels, labels, patches=patches), steps)
    except SceneError as exc:
        raise SceneError(str(path), str(exc)) from exc
    return place_mesh(mesh, unit, R, t)
