"""Truth where users look: ParaView files, written with pyevtk (ImageData, collections) and meshio
(the FE mesh).

- :func:`write_truth_vti`: one image's truth as a VTK ImageData (``.vti``) whose points are the
  pixel centres (x = u, y = v, spacing 1 px, so rows run down as in the image) with the maps as
  point arrays: ``mask`` (uint8), ``element`` (int32, −1 outside), ``xi``, ``eta``, ``ref_u``,
  ``ref_v`` (px), and the vectors ``X_undeformed``, ``X_deformed``, ``displacement`` (mm, camera
  0's frame); floats are NaN outside the mask, as in the ``.npz``.
- :func:`write_mesh_series`: the FE mesh in camera 0's frame, one ``.vtu`` per load step (points
  at the undeformed positions, ``displacement`` as point data, so ParaView's *Warp By Vector*
  shows each step) and a ``.pvd`` collection over the steps (the solver's times where known).
- :func:`check_vtu`: a ``.vtu`` to be read, its declared sizes bounded before meshio decodes it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.io.atomic import atomic_path, atomic_paths
from glsim.scene.camera import Camera, to_camera
from glsim.scene.mesh import Mesh


def _point_data(truth: dict[str, np.ndarray]) -> dict:
    """pyevtk point data: (W, H, 1) arrays in x = u, y = v order; vectors as 3 such arrays."""
    def grid(a):
        return np.ascontiguousarray(np.asarray(a).T[..., None])

    def vector(a):
        return tuple(grid(a[..., i]).astype(np.float64) for i in range(3))
    X0, X1 = truth["X_undeformed"], truth["X_deformed"]
    return {"mask": grid(truth["mask"]).astype(np.uint8), "element": grid(truth["element"]).astype(np.int32),
            "xi": grid(truth["xi"]).astype(np.float64), "eta": grid(truth["eta"]).astype(np.float64),
            "ref_u": grid(truth["ref_uv"][..., 0]).astype(np.float64),
            "ref_v": grid(truth["ref_uv"][..., 1]).astype(np.float64),
            "X_undeformed": vector(X0), "X_deformed": vector(X1), "displacement": vector(X1 - X0)}


def write_vti_file(tmp: Path, truth: dict[str, np.ndarray]) -> None:
    """Write ``truth`` as ImageData to ``tmp``, a path ending in ``.vti`` (pyevtk appends it)."""
    from pyevtk.hl import imageToVTK

    imageToVTK(str(tmp.with_suffix("")), pointData=_point_data(truth))     # writes tmp itself


def write_truth_vti(path: str | Path, truth: dict[str, np.ndarray]) -> Path:
    """One image's truth maps as a ``.vti``, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        write_vti_file(tmp, truth)
    return path


def write_mesh_series(directory: str | Path, mesh: Mesh, cam: Camera, name: str = "mesh") -> list[Path]:
    """``{name}_{step:04d}.vtu`` per load step and ``{name}.pvd`` in ``directory``, in ``cam``'s
    frame (mm), written atomically as one group (the ``.pvd`` last)."""
    import meshio

    directory = Path(directory)
    X0 = to_camera(mesh.nodes, cam)
    tri = mesh.quads[:, 2] == mesh.quads[:, 3]                 # triangles stored as collapsed quads
    if mesh.is_quadratic:   # the source element types: quad8 (derived centre), quad9, triangle6
        p = mesh.patches
        q8, t6 = p[:, 8] == -1, p[:, 8] == -2                   # glsim.scene.quadratic's centre codes
        blocks = (("quad8", p[q8, :8]), ("quad9", p[~q8 & ~t6]), ("triangle6", p[t6][:, [0, 1, 2, 4, 5, 7]]))
    else:
        blocks = (("quad", mesh.quads[~tri]), ("triangle", mesh.quads[tri, :3]))
    cells = [(kind, block) for kind, block in blocks if len(block)]
    steps = range(mesh.n_steps)
    vtus = [directory / f"{name}_{k:04d}.vtu" for k in steps]
    pvd = directory / f"{name}.pvd"
    times = [t if t is not None else float(k) for k, t in
             zip(steps, mesh.step_times or [None] * mesh.n_steps)]
    with atomic_paths([*vtus, pvd]) as tmps:
        for tmp, k in zip(tmps, steps):
            u = to_camera(mesh.nodes + mesh.displacements[k], cam) - X0
            meshio.write(tmp, meshio.Mesh(X0, cells, point_data={"displacement": u, "node_label": mesh.node_labels}),
                         file_format="vtu")
        datasets = "\n".join(f'    <DataSet timestep="{t!r}" part="0" file="{v.name}"/>' for t, v in zip(times, vtus))
        tmps[-1].write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" '
                            f'byte_order="LittleEndian">\n  <Collection>\n{datasets}\n  </Collection>\n</VTKFile>\n')
    return [*vtus, pvd]


# ---- reading: a .vtu's declared sizes, bounded before meshio decodes it ---------------------------

_VTU_TYPES = {"Int8": 1, "UInt8": 1, "Int16": 2, "UInt16": 2, "Int32": 4, "UInt32": 4, "Int64": 8, "UInt64": 8,
              "Float32": 4, "Float64": 8}
_VTU_FIX = "write or export the file again (damaged, or not what it declares)"
VTU_DECODED_COPIES = 3   # meshio holds a decoded array up to 3 times (bytes, re-encoded text, the array)


def check_vtu(path: Path) -> None:
    """SceneError naming the array if a VTU file's declared sizes cannot be true or cannot fit:
    NumberOfPoints/NumberOfCells go into the memory estimate (with every data array's declared
    size), each binary array's header must declare what those counts give it (points and point
    data: points × components, cell data, offsets, types: cells × components), and each compressed
    block must inflate to no more than its header declares — checked by inflating it at most one
    byte further, so a zlib bomb is refused, not decompressed. A file it cannot parse is left to
    meshio, which names the problem."""
    from glsim.limits import check_mesh_memory, check_need

    size = path.stat().st_size
    check_need(str(path), VTU_DECODED_COPIES * size, f"its {size:,} bytes need", "give a smaller .vtu file")
    layout = _vtu_layout(path.read_bytes())
    if layout is None:
        return
    root, appended, appended_base64 = layout
    header = np.dtype(_VTU_HEADERS.get(root.get("header_type", "UInt32"), "<u4"))
    if root.get("byte_order") == "BigEndian":
        header = header.newbyteorder(">")
    compressor = root.get("compressor")
    try:
        pieces = [(piece, int(piece.get("NumberOfPoints", 0)), int(piece.get("NumberOfCells", 0)))
                  for piece in root.iter("Piece")]
    except ValueError:
        return
    points, cells = sum(p for _, p, _ in pieces), sum(c for _, _, c in pieces)
    what = " (its pieces and data arrays)"
    check_mesh_memory(str(path), points, cells, what=what)          # before a block is inflated
    decoded = 0
    for piece, n_points, n_cells in pieces:
        for section in piece:
            for array in section:
                count = _expected_count(section.tag, array, n_points, n_cells)
                decoded += _check_array(path, array, count, header, compressor, appended, appended_base64)
    for field_data in root.iter("FieldData"):
        for array in field_data:
            decoded += _check_array(path, array, None, header, compressor, appended, appended_base64)
    check_mesh_memory(str(path), points, cells, VTU_DECODED_COPIES * decoded, what)


_VTU_HEADERS = {"UInt32": "<u4", "UInt64": "<u8"}


def _vtu_layout(raw: bytes):
    """(XML root without the appended data, the appended data after its '_', whether that is base64),
    or None where the file is not XML meshio could read (meshio then names the problem)."""
    import re
    from xml.etree import ElementTree as ET

    appended, base64_text = None, False
    found = re.search(rb"<AppendedData\b[^>]*>", raw)
    if found:
        end = raw.rfind(b"</AppendedData>")
        body = raw[found.end():end] if end > found.end() else b""
        start = body.find(b"_")
        if start < 0:
            return None
        base64_text = b'encoding="base64"' in found.group(0) or b"encoding='base64'" in found.group(0)
        appended = body[start + 1:].strip() if base64_text else body[start + 1:]
        raw = raw[:found.end()] + raw[end:]
    try:
        return ET.fromstring(raw), appended, base64_text
    except ET.ParseError:
        return None


def _expected_count(section: str, array, n_points: int, n_cells: int) -> int | None:
    """Values an array must hold for the counts of its piece (None: not fixed by them)."""
    try:
        components = int(array.get("NumberOfComponents") or 1)
    except ValueError:
        return None
    if section in ("Points", "PointData"):
        return n_points * components
    if section == "CellData" or (section == "Cells" and array.get("Name") in ("offsets", "types")):
        return n_cells * components
    return None


def _b64_chars(n: int) -> int:
    return -(-n // 3) * 4


def _check_array(path: Path, array, count: int | None, header: np.dtype, compressor: str | None,
                 appended: bytes | None, appended_base64: bool) -> int:
    """Bytes the binary ``array`` decodes to, refused (SceneError) unless it declares ``count``
    values (where given) and every compressed block inflates within its declared size. Its data:
    a header of ``header`` integers, then the (compressed) bytes; in base64, the two are encoded
    apart (as VTK and meshio write and read them)."""
    import base64

    fmt, item = array.get("format", "ascii"), _VTU_TYPES.get(array.get("type", ""))
    if item is None or fmt not in ("binary", "appended"):
        return 8 * len(array.text or "")            # ascii: at most a value per 2 characters, 8 bytes each
    try:
        data, encoded = (((array.text or "").strip().encode(), True) if fmt == "binary" else
                         (appended[int(array.get("offset", 0)):], appended_base64))
        w = header.itemsize
        first = base64.b64decode(data[:_b64_chars(w)])[:w] if encoded else data[:w]
        n = int(np.frombuffer(first, header)[0])
    except (ValueError, IndexError, TypeError):
        return 0                                     # meshio names it
    name = f"data array {array.get('Name', '?')!r}"
    if compressor is None:
        declared = n
    else:
        if n * w > len(data):
            raise SceneError(str(path), f"{name} declares {n:,} compressed blocks, more than the file holds", _VTU_FIX)
        size = (3 + n) * w
        try:
            head = np.frombuffer(base64.b64decode(data[:_b64_chars(size)]) if encoded else data[:size], header)
        except ValueError:
            return 0
        head = head.astype(np.int64)
        if len(head) < 3 + n:
            return 0
        block, last = int(head[1]), int(head[2]) or int(head[1])
        declared = block * (n - 1) + last if n else 0
    if count is not None and declared != count * item:
        raise SceneError(str(path), f"{name} declares {declared:,} bytes, where its piece's counts give "
                         f"{count:,} values of {item} bytes", _VTU_FIX)
    if compressor is not None and n:
        start = _b64_chars(size) if encoded else size
        compressed = [int(c) for c in head[3:]]
        stream = data[start:start + (_b64_chars(sum(compressed)) if encoded else sum(compressed))]
        try:
            stream = base64.b64decode(stream) if encoded else stream
        except ValueError:
            return declared
        _check_blocks(path, name, stream, compressed, [block] * (n - 1) + [last], compressor)
    return declared


def _check_blocks(path: Path, name: str, stream: bytes, compressed: list[int], sizes: list[int],
                  compressor: str) -> None:
    """Each compressed block inflated at most one byte past its declared size: a block that gives
    more (a zlib bomb) is refused before meshio inflates it whole. Damaged blocks are left to meshio."""
    import lzma
    import zlib

    at = 0
    for k, (c, limit) in enumerate(zip(compressed, sizes)):
        block, at = stream[at:at + c], at + c
        try:
            d = zlib.decompressobj() if compressor == "vtkZLibDataCompressor" else lzma.LZMADecompressor()
            got = len(d.decompress(block, limit))
            more = b"" if getattr(d, "eof", False) else d.decompress(getattr(d, "unconsumed_tail", b""), 1)
        except (zlib.error, lzma.LZMAError, EOFError):
            return
        if more or got > limit:
            raise SceneError(str(path), f"{name}: compressed block {k + 1} inflates to more than the {limit:,} bytes "
                             "its header declares (a decompression bomb?); not inflated", _VTU_FIX)
