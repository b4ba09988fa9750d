"""Hostile files for glsim's readers: each is refused by name — the file or the culprit in it, and
the fix — from what its header declares, before the reader allocates it (no MemoryError, no
traceback, exit status 2, nothing written). Mesh files (Exodus II netCDF-4, VTU, legacy VTK, Gmsh,
Abaqus *INCLUDE) and images (the reference, a measured PSF) are crafted here byte by byte; every
case runs again in one subprocess limited to 500 MB of address space, where a reader that believed
its header would run out of memory. Legitimate files still load."""
import functools
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from _hostile import files, main_under_cap, tiff, write

from glsim.cli import main
from glsim.errors import SceneError
from glsim.io import images
from glsim.io.fe import load_mesh, open_series

netCDF4 = pytest.importorskip("netCDF4")



SCENE = ('[[cameras]]\nname = "cam0"\nsize = [64, 48]\nfx = 300.0\nfy = 300.0\ncx = 31.5\ncy = 23.5\n'
         '{specimen}[specimen.pose]\nt = [0.0, 0.0, 300.0]\n[speckle]\n{speckle}[render]\nbackend = "cpu"\n')
PLATE = "[specimen.plate]\nwidth = 40.0\nheight = 30.0\ntranslations = [[0.1, 0.0, 0.0]]\n"
QUAD = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0.0]])


def mesh_scene(d: Path, name: str, extra: str = "") -> Path:
    """A scene whose specimen is the mesh file ``name`` in ``d``."""
    return write(d / "scene.toml", SCENE.format(specimen=f'[specimen.mesh]\npath = "{name}"\n{extra}',
                                                speckle="dot_diameter_px = 4.0\n"))


def image_scene(d: Path, speckle: str = "dot_diameter_px = 4.0\n", psf: str = "") -> Path:
    return write(d / "scene.toml", SCENE.format(specimen=PLATE, speckle=speckle) + psf)


# ---- crafted files -----------------------------------------------------------------------------------

def exodus(path: Path, n_nodes: int = 6, coords: bool = True, blocks: int = 2, connect: int = 2,
           times=(0.0, 1.0), fmt: str = "NETCDF4", declared_blocks: int | None = None) -> Path:
    """Two QUAD4 blocks on 6 nodes (``n_nodes`` declared), written with netCDF4 in the Exodus II
    layout; ``connect`` of the blocks get their connect{i}, ``coords=False`` leaves coordx/coordy
    unwritten (netCDF's fill value); ``declared_blocks``: num_el_blk, where not ``blocks``."""
    with netCDF4.Dataset(path, "w", format=fmt) as ds:
        for name, size in (("len_name", 33), ("time_step", None), ("num_dim", 2), ("num_nodes", n_nodes),
                           ("num_el_blk", declared_blocks or blocks)):
            ds.createDimension(name, size)
        ds.createVariable("time_whole", "f8", ("time_step",))[:] = np.asarray(times, float)
        for axis, values in (("x", [0, 10, 10, 0, 20, 20]), ("y", [0, 0, 10, 10, 0, 10])):
            var = ds.createVariable("coord" + axis, "f8", ("num_nodes",), zlib=fmt == "NETCDF4")
            if coords:
                var[:6] = values
        for i, conn in enumerate([[1, 2, 3, 4], [2, 5, 6, 3]][:blocks], 1):
            ds.createDimension(f"num_el_in_blk{i}", 1)
            ds.createDimension(f"num_nod_per_el{i}", 4)
            if i <= connect:
                var = ds.createVariable(f"connect{i}", "i4", (f"num_el_in_blk{i}", f"num_nod_per_el{i}"))
                var.elem_type = "QUAD4"
                var[:] = [conn]
    return path


def vtu_array(name: str, kind: str, payload: bytes, components: int = 1, declared: int | None = None,
              block: int | None = None) -> str:
    """A zlib-compressed inline binary DataArray (one block; its header may declare ``declared``
    bytes other than ``payload``'s) as VTK writes it: header and blocks base64-encoded apart."""
    import base64
    packed = zlib.compress(payload) if isinstance(payload, bytes) else payload()
    size = len(payload) if declared is None and isinstance(payload, bytes) else declared
    head = struct.pack("<4I", 1, block or size, size, len(packed))
    text = (base64.b64encode(head) + base64.b64encode(packed)).decode()
    return (f'<DataArray type="{kind}" Name="{name}" NumberOfComponents="{components}" format="binary">'
            f"{text}</DataArray>")


@functools.lru_cache(maxsize=1)
def zlib_bomb() -> bytes:
    """1 GiB of zeros, zlib-compressed (about 1 MB)."""
    z = zlib.compressobj(9)
    chunk = bytes(1 << 20)
    return b"".join(z.compress(chunk) for _ in range(1024)) + z.flush()


def vtu(points: int = 4, cells: int = 1, extra_point_data: str = "", kind: int = 9, conn=(0, 1, 2, 3)) -> bytes:
    """A one-cell .vtu (zlib-compressed inline binary), with extra point-data arrays."""
    pts = vtu_array("Points", "Float64", np.pad(QUAD, ((0, points - 4), (0, 0))).astype("<f8").tobytes()
                    if points <= 64 else QUAD.astype("<f8").tobytes(), 3, declared=points * 24)
    cells_xml = (vtu_array("connectivity", "Int64", np.array(conn, "<i8").tobytes())
                 + vtu_array("offsets", "Int64", np.array([len(conn)], "<i8").tobytes(), declared=cells * 8)
                 + vtu_array("types", "UInt8", bytes([kind]), declared=cells))
    return (f'<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="0.1" byte_order="LittleEndian" '
            f'header_type="UInt32" compressor="vtkZLibDataCompressor">\n<UnstructuredGrid>\n'
            f'<Piece NumberOfPoints="{points}" NumberOfCells="{cells}">\n<Points>{pts}</Points>\n'
            f'<Cells>{cells_xml}</Cells>\n<PointData>{extra_point_data}</PointData>\n</Piece>\n'
            f'</UnstructuredGrid>\n</VTKFile>\n').encode()


def vtu_bomb() -> bytes:
    """A .vtu whose unused point-data array 'junk' declares 32 bytes and inflates to 1 GiB."""
    return vtu(extra_point_data=vtu_array("junk", "Float64", zlib_bomb, declared=32))


def png(path: Path, side: int) -> Path:
    """A 4 × 4 grey PNG whose IHDR says ``side`` × ``side``."""
    import imageio.v3 as iio
    iio.imwrite(path, np.zeros((4, 4), np.uint8), extension=".png")
    b = bytearray(path.read_bytes())
    struct.pack_into(">II", b, 16, side, side)
    struct.pack_into(">I", b, 29, zlib.crc32(bytes(b[12:29])))
    return write(path, bytes(b))


INP = "*NODE\n1, 0.0, 0.0, 0.0\n2, 10.0, 0.0, 0.0\n3, 10.0, 10.0, 0.0\n4, 0.0, 10.0, 0.0\n{include}" \
      "*ELEMENT, TYPE=S4R\n1, 1, 2, 3, 4\n"


# ---- each case: d → (argv, the culprit the message names) -------------------------------------------

def _render(scene: Path) -> list:
    return ["render", str(scene), "-o", str(scene.parent / "out"), "-q"]


def _mesh(name: str, content, extra: str = ""):
    def case(d: Path):
        write(d / name, content() if callable(content) else content)
        return _render(mesh_scene(d, name, extra))
    return case


CASES = {
    # Exodus II
    "Exodus netCDF-4 of 4e8 nodes": (lambda d: _render(mesh_scene(d, exodus(d / "m.e", 400_000_000).name)),
                                     "m.e: declares 400,000,000 nodes and 2 elements"),
    "Exodus block without connect": (lambda d: _render(mesh_scene(d, exodus(d / "m.e", connect=1).name)),
                                     "m.e: element block id 2 declares 1 element (num_el_in_blk2) but the file "
                                     "has no connect2"),
    "Exodus coordinates never written": (lambda d: _render(mesh_scene(d, exodus(d / "m.e", coords=False).name)),
                                         "m.e: variable 'coordx' holds the netCDF fill value (never written) at 6 "
                                         "nodes (first: node 1, 9.96921e+36)"),
    "Exodus NaN time": (lambda d: _render(mesh_scene(d, exodus(d / "m.e", times=(0.0, float("nan"))).name)),
                        "m.e: time_whole holds nan at stored step 1"),
    "Exodus num_el_blk 1e9": (lambda d: _render(mesh_scene(d, exodus(d / "m.e", declared_blocks=10**9).name)),
                              "m.e: declares 1,000,000,000 element blocks (num_el_blk) but has only"),
    # VTU
    "VTU zlib bomb in unused point data": (_mesh("m.vtu", vtu_bomb),
                                           "m.vtu: data array 'junk': compressed block 1 inflates to more than the "
                                           "32 bytes its header declares"),
    "VTU of 1e8 points": (_mesh("m.vtu", lambda: vtu(points=100_000_000)), "m.vtu: declares 100,000,000 nodes"),
    "VTU array larger than its counts": (_mesh("m.vtu", lambda: vtu(extra_point_data=vtu_array(
        "u", "Float64", bytes(800_000), 3))), "m.vtu: data array 'u' declares 800,000 bytes, where its piece's counts "
                                             "give 12 values of 8 bytes"),
    "VTU hexahedron out of range": (_mesh("m.vtu", lambda: vtu(points=8, kind=12, conn=(0, 1, 2, 3, 4, 5, 6, 99))),
                                    "m.vtu: hexahedron element 1 refers to node 100 (1-based position), outside "
                                    "the file's 8 nodes"),
    "VTU tetra out of range": (_mesh("m.vtu", lambda: vtu(kind=10, conn=(0, 1, -5, 3))),
                               "m.vtu: tetra element 1 refers to node -4"),
    # legacy VTK, Gmsh
    "legacy VTK of 4e8 points": (_mesh("m.vtk", "# vtk DataFile Version 4.2\nx\nBINARY\nDATASET UNSTRUCTURED_GRID\n"
                                                "POINTS 400000000 double\n" + "\0" * 96),
                                 "m.vtk: POINTS declares 400,000,000 items, more than its"),
    "Gmsh 2 of 1e12 nodes": (_mesh("m.msh", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000000\n"
                                            "1 0 0 0\n$EndNodes\n"),
                             "m.msh: its $Nodes section declares 1,000,000,000,000 entries in 1 blocks, more than "
                             "its"),
    "Gmsh 4 binary of 1e9 elements": (_mesh("m.msh", lambda: b"$MeshFormat\n4.1 1 8\n" + struct.pack("<i", 1)
                                            + b"\n$EndMeshFormat\n$Elements\n" + struct.pack("<4Q", 1, 10**9, 1, 10**9)
                                            + bytes(64) + b"\n$EndElements\n"),
                                      "m.msh: its $Elements section declares 1,000,000,000 entries"),
    "Gmsh 4 ASCII node tag 1e15": (_mesh("m.msh", "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n1 4 1 "
                                                  "1000000000000000\n2 1 0 4\n1\n2\n3\n1000000000000000\n0 0 0\n1 0 0\n"
                                                  "1 1 0\n0 1 0\n$EndNodes\n"),
                                   "m.msh: declares 4 nodes and 0 elements (its $Nodes and $Elements), which need"),
    # Abaqus *INCLUDE
    "Abaqus *INCLUDE /dev/zero": (_mesh("m.inp", INP.format(include="*INCLUDE, INPUT=/dev/zero\n")),
                                  "m.inp: *INCLUDE, INPUT=/dev/zero: /dev/zero is a character device, not a file"),
    "Abaqus *INCLUDE outside": (lambda d: (write(d.parent / "outside.inp", "** nothing\n"), _mesh("m.inp", INP.format(
                                    include="*INCLUDE, INPUT=../outside.inp\n"))(d))[1],
                                "m.inp: *INCLUDE, INPUT=../outside.inp: {d.parent}/outside.inp lies outside the mesh "
                                "and scene folders (not read)"),
    "Abaqus *INCLUDE of itself": (_mesh("m.inp", INP.format(include="*INCLUDE, INPUT=m.inp\n")),
                                  "includes nest more than 16 deep or include themselves (m.inp → m.inp)"),
    # images
    "RGBA16 TIFF reference": (lambda d: _render(image_scene(d, 'image = "ref.tif"\nmm_per_px = 0.05\n'
                                                           if tiff(d / "ref.tif", np.zeros((4, 4, 4), np.uint16), 8000,
                                                                   photometric="rgb") else "")),
                              "ref.tif is a colour image (its header declares 4 samples per pixel)"),
    "volume TIFF reference": (lambda d: _render(image_scene(d, 'image = "ref.tif"\nmm_per_px = 0.05\n'
                                                           if tiff(d / "ref.tif", np.zeros((300, 64, 64), np.uint8))
                                                           else "")),
                              "ref.tif is not a single greyscale image (its header declares 300 pages or slices)"),
    "int32 TIFF reference": (lambda d: _render(image_scene(d, 'image = "ref.tif"\nmm_per_px = 0.05\n'
                                                          if tiff(d / "ref.tif", np.zeros((8, 8), np.int32), 8000)
                                                          else "")),
                             "ref.tif has unsupported pixel type int32 (as its header declares)"),
    "PSF image 16000² PNG": (lambda d: _render(image_scene(d, psf='[psf]\nkind = "image"\nimage = "psf.png"\n')
                                               if png(d / "psf.png", 16000) else None),
                             "psf.png (as its header declares) is 16000 × 16000 px; the limit is 129 px"),
    "PSF image /dev/zero": (lambda d: _render(image_scene(d, psf='[psf]\nkind = "image"\nimage = "/dev/zero"\n')),
                            "psf.image: /dev/zero is a character device, not a file"),
}
# refused only where the machine has less memory than they need: in the capped subprocess alone
CAPPED = {
    "16384² 16-bit reference": (lambda d: _render(image_scene(d, 'image = "ref.tif"\nmm_per_px = 0.05\n'
                                                             if tiff(d / "ref.tif", np.zeros((8, 8), np.uint16), 16384)
                                                             else "")),
                                "ref.tif (16384 × 16384 px, as its header declares) needs about 8.5 GiB to read"),
    "Exodus netCDF-4 of 1e6 nodes": (lambda d: _render(mesh_scene(d, exodus(d / "m.e", 1_000_000).name)),
                                     "m.e: declares 1,000,000 nodes and 2 elements"),
}


def _run(case, d: Path, capsys):
    argv = case[0](d)
    before = files(d)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert files(d) == before and not (d / "out").exists()
    return err


@pytest.mark.parametrize("name", list(CASES))
def test_a_hostile_file_is_refused_by_name_writing_nothing(tmp_path, capsys, name):
    d = tmp_path / "in"
    d.mkdir()
    err = _run(CASES[name], d, capsys)
    assert CASES[name][1].format(d=d) in err, err
    assert "Traceback" not in err and " — " in err          # the fix follows the problem


@pytest.mark.process
def test_every_case_is_refused_under_a_500_MB_address_space_limit(tmp_path):
    cases = {**CASES, **CAPPED}
    argvs = []
    for i, case in enumerate(cases.values()):
        d = tmp_path / f"c{i}"
        d.mkdir()
        argvs.append(case[0](d))
    results = main_under_cap(argvs)
    for i, ((name, (_, culprit)), (rc, err)) in enumerate(zip(cases.items(), results)):
        assert rc == 2 and culprit.format(d=tmp_path / f"c{i}") in err and "Traceback" not in err, (name, rc, err)


# ---- legitimate files still load ---------------------------------------------------------------------

def test_legitimate_files_load(tmp_path):
    """The crafted writers' honest files: a VTU with a used point-data array, an Abaqus file that
    includes its nodes from its own folder, a netCDF-4 and a classic Exodus file."""
    u = np.tile([0.5, 0.0, 0.0], (4, 1)).astype("<f8")
    m = load_mesh(write(tmp_path / "m.vtu", vtu(extra_point_data=vtu_array("u", "Float64", u.tobytes(), 3))),
                  point_data_steps=["u"])
    np.testing.assert_array_equal(m.displacements[1], u)
    write(tmp_path / "steel.inp", "*MATERIAL, NAME=steel\n*ELASTIC\n210000.0, 0.3\n")
    m = load_mesh(write(tmp_path / "a.inp", INP.format(include="*INCLUDE, INPUT=steel.inp\n")))
    assert len(m.nodes) == 4 and len(m.quads) == 1
    for fmt in ("NETCDF4", "NETCDF3_64BIT_OFFSET"):
        with open_series(exodus(tmp_path / f"{fmt}.e", fmt=fmt)) as s:
            assert s.points.shape == (6, 3) and [len(c) for _, c in s.cells] == [1, 1]
            np.testing.assert_array_equal(s.times, [0.0, 1.0])


def test_a_hex_out_of_range_in_memory_is_named_not_an_index_error(tmp_path):
    import meshio
    path = tmp_path / "hex.vtu"
    meshio.Mesh(np.vstack([QUAD, QUAD + [0, 0, 5]]), [("hexahedron", np.array([[0, 1, 2, 3, 4, 5, 6, 8]]))]).write(path)
    with pytest.raises(SceneError, match=r"hexahedron element 1 refers to node 9 \(1-based position\), outside the "
                                         r"file's 8 nodes"):
        load_mesh(path)


# ---- the estimates refuse what cannot fit, not what is big ------------------------------------------

def test_the_mesh_estimate_refuses_what_cannot_fit_not_what_is_big(tmp_path, monkeypatch):
    """A 10⁶-element mesh is estimated at 4 GB (MESH_BYTES_PER_NODE, MESH_BYTES_PER_ELEMENT):
    it passes on a machine of 8 GiB, and is refused by name on one of 2 GiB."""
    from glsim import limits
    path = write(tmp_path / "m.msh", "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000\n"
                 + "1 0 0 0\n" * 2 + "$EndNodes\n$Elements\n1000000\n" + "$EndElements\n")
    path.write_bytes(path.read_bytes() + bytes(16_000_000))        # a length that can hold the counts
    from glsim.io.meshfiles import check_mesh_file
    monkeypatch.setattr(limits, "memory_budget", lambda: 8 << 30)
    check_mesh_file(path)
    monkeypatch.setattr(limits, "memory_budget", lambda: 2 << 30)
    with pytest.raises(SceneError, match=r"m.msh: declares 1,000,000 nodes and 1,000,000 elements \(its \$Nodes and "
                                         r"\$Elements\), which need about 3.81 GiB, more than the 2 GiB"):
        check_mesh_file(path)


def test_the_reference_estimate_covers_its_float64_temporaries(tmp_path, monkeypatch):
    """A 16384² 16-bit reference: 2 bytes a pixel decoded and REFERENCE_BYTES_PER_PIXEL more,
    8.5 GiB — read on a machine of 16 GiB, refused by name before decoding on one of 8."""
    from glsim import limits
    path = tiff(tmp_path / "ref.tif", np.zeros((8, 8), np.uint16), 16384)
    monkeypatch.setattr(limits, "memory_budget", lambda: 16 << 30)
    images.check_image_file(path, "speckle.image")
    monkeypatch.setattr(limits, "memory_budget", lambda: 8 << 30)
    with pytest.raises(SceneError, match=r"speckle.image: .*ref.tif \(16384 × 16384 px, as its header declares\) "
                                         r"needs about 8.5 GiB to read, more than the 8 GiB"):
        images.check_image_file(path, "speckle.image")
