"""Hostile Gmsh MSH 4 and XDMF files: what their entity blocks and DataItems declare is bounded before
meshio allocates it — each MSH 4 block's node or element count against its section's total and the
bytes left in the file, its node tags against the memory estimate; each XDMF DataItem's Dimensions
against its text, binary file or HDF5 dataset (its shape, from metadata) and the memory budget, an
Attribute against the node or element count, the topology's node indices against the nodes. Each
is refused by name (the file and the culprit, exit status 2, no traceback, nothing written), also
in one subprocess limited to 500 MB of address space, where a reader that believed the file would
run out of memory first. Honest files still load, as meshio reads them."""
import struct
from pathlib import Path

import meshio
import numpy as np
import pytest
from _hostile import files, main_under_cap, write

from glsim.cli import main
from glsim.errors import SceneError
from glsim.io.fe import load_mesh, open_series
from glsim.io.meshfiles import check_mesh_file

h5py = pytest.importorskip("h5py")

SCENE = ('[[cameras]]\nname = "cam0"\nsize = [64, 48]\nfx = 300.0\nfy = 300.0\ncx = 31.5\ncy = 23.5\n'
         '[specimen.mesh]\npath = "{name}"\n{extra}[specimen.pose]\nt = [0.0, 0.0, 300.0]\n[speckle]\n'
         'dot_diameter_px = 4.0\n[render]\nbackend = "cpu"\n')
POINTS = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0], [20, 0, 0], [20, 10, 0.0]])
QUADS = np.array([[0, 1, 2, 3], [1, 4, 5, 2]])


def render(d: Path, name: str, extra: str = "") -> list:
    scene = write(d / "scene.toml", SCENE.format(name=name, extra=extra))
    return ["render", str(scene), "-o", str(d / "out"), "-q"]


# ---- Gmsh MSH 4, crafted -----------------------------------------------------------------------------

HEAD_ASCII = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n"
HEAD_BINARY = b"$MeshFormat\n4.1 1 8\n" + struct.pack("<i", 1) + b"\n$EndMeshFormat\n"
ELEMENTS_ASCII = "$Elements\n1 1 1 1\n2 1 3 1\n1 1 2 3 4\n$EndElements\n"
NODES_ASCII = "$Nodes\n1 4 1 4\n2 1 0 4\n1\n2\n3\n4\n0 0 0\n10 0 0\n10 10 0\n0 10 0\n$EndNodes\n"


def binary_nodes(declared: int, tags=(1, 2, 3, 4), total: int = 4, max_tag: int = 4) -> bytes:
    """A binary MSH 4.1 $Nodes section of one entity block declaring ``declared`` nodes (its data: ``tags``)."""
    xyz = POINTS[:len(tags)].astype("<f8").tobytes()
    return (b"$Nodes\n" + struct.pack("<4Q", 1, total, 1, max_tag) + struct.pack("<3iQ", 2, 1, 0, declared)
            + np.asarray(tags, "<u8").tobytes() + xyz + b"\n$EndNodes\n")


def binary_elements(declared: int, total: int = 1, nodes=(1, 2, 3, 4)) -> bytes:
    """A binary MSH 4.1 $Elements section of one block of quads declaring ``declared`` (its data: one quad)."""
    return (b"$Elements\n" + struct.pack("<4Q", 1, total, 1, total) + struct.pack("<3iQ", 2, 1, 3, declared)
            + np.array([1, *nodes], "<u8").tobytes() + b"\n$EndElements\n")


def _msh(content, name: str = "m.msh"):
    def case(d: Path):
        write(d / name, content() if callable(content) else content)
        return render(d, name)
    return case


GMSH = {
    "MSH4 ASCII block of 1e12 nodes": (
        _msh(HEAD_ASCII + "$Nodes\n1 1 1 1\n2 1 0 1000000000000\n1\n0 0 0\n$EndNodes\n" + ELEMENTS_ASCII),
        "m.msh: its $Nodes section: entity block 1 declares 1,000,000,000,000 nodes, more than the 1 its section "
        "declares"),
    "MSH4 binary block of 1e12 nodes": (
        _msh(lambda: HEAD_BINARY + binary_nodes(10**12, tags=(1,), total=1, max_tag=1) + binary_elements(1)),
        "m.msh: its $Nodes section: entity block 1 declares 1,000,000,000,000 nodes, more than the 1 its section "
        "declares"),
    "MSH4 ASCII block of more nodes than the bytes left": (      # block 1's long numbers take the bytes
        _msh(HEAD_ASCII + "$Nodes\n2 20 1 20\n2 1 0 1\n1\n0." + "0" * 400 + " 0 0\n2 2 0 19\n$EndNodes\n"),
        "m.msh: its $Nodes section: entity block 2 declares 19 nodes, more than the 10 bytes left in the file can "
        "hold"),
    "MSH4 ASCII block of 1e12 elements": (
        _msh(HEAD_ASCII + NODES_ASCII + "$Elements\n1 1 1 1\n2 1 3 1000000000000\n1 1 2 3 4\n$EndElements\n"),
        "m.msh: its $Elements section: entity block 1 declares 1,000,000,000,000 elements, more than the 1 its "
        "section declares"),
    "MSH4 binary block of tetra10 elements, more than the bytes left": (   # the section's total fits
        _msh(lambda: HEAD_BINARY + binary_nodes(4) + b"$Elements\n" + struct.pack("<4Q", 1, 1000, 1, 1000)
             + struct.pack("<3iQ", 3, 1, 11, 1000) + b"\n$EndElements\n$Comments\n" + bytes(20_000)
             + b"\n$EndComments\n"),
        "m.msh: its $Elements section: entity block 1 declares 1,000 elements of 10 nodes, more than the 20,038 "
        "bytes left in the file can hold"),
    "MSH4 ASCII node tag 1e15 under a header of 4": (
        _msh(HEAD_ASCII + "$Nodes\n1 4 1 4\n2 1 0 4\n1\n2\n3\n1000000000000000\n0 0 0\n10 0 0\n10 10 0\n0 10 0\n"
             "$EndNodes\n" + ELEMENTS_ASCII),
        "m.msh: declares 4 nodes and 0 elements (its $Nodes, with node tags up to 1,000,000,000,000,000 in entity "
        "block 1), which need"),
    "MSH4 a real $Nodes after a harmless one in $Comments": (
        _msh(HEAD_ASCII + "$Comments\n$Nodes\n1 1 1 1\n2 1 0 1\n1\n0 0 0\n$EndNodes\n$EndComments\n"
             "$Nodes\n1 1000000000000 1 1\n2 1 0 1000000000000\n1\n0 0 0\n$EndNodes\n"),
        "m.msh: its $Nodes section declares 1,000,000,000,000 nodes in 1 blocks, more than the"),
    "MSH4 a real $Nodes after an unreadable one in $Comments": (
        _msh(HEAD_ASCII + "$Comments\n$Nodes\nnot a count\n$EndComments\n"
             "$Nodes\n1 1000000000000 1 1\n2 1 0 1000000000000\n1\n0 0 0\n$EndNodes\n"),
        "m.msh: its $Nodes section declares 1,000,000,000,000 nodes in 1 blocks, more than the"),
    "MSH2 behind $Comments, 1e12 nodes": (
        _msh("$Comments\nmade by hand\n$EndComments\n$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n1000000000000\n"
             "1 0 0 0\n$EndNodes\n"),
        "m.msh: its $Nodes section declares 1,000,000,000,000 entries in 1 blocks, more than its"),
    "MSH4 $Entities with 1e12 physical tags": (
        _msh(HEAD_ASCII + "$Entities\n1 0 0 0\n1 0 0 0 1000000000000 1\n$EndEntities\n" + NODES_ASCII
             + ELEMENTS_ASCII),
        "m.msh: its $Entities section: entity 1 of dimension 0's physical tags declares 1,000,000,000,000 values, "
        "more than the"),
    "MSH4 $NodeData of 1e12 items": (
        _msh(HEAD_ASCII + NODES_ASCII + ELEMENTS_ASCII + '$NodeData\n1\n"u"\n1\n0.0\n3\n0\n3\n1000000000000\n'
             "1 0 0 0\n$EndNodeData\n"),
        "m.msh: its $NodeData section's 1,000,000,000,000 items declares 4,000,000,000,000 values, more than the"),
    "MSH2 binary element block of 1e9 elements": (
        _msh(lambda: b"$MeshFormat\n2.2 1 8\n" + struct.pack("<i", 1) + b"\n$EndMeshFormat\n$Nodes\n4\n"
             + b"".join(struct.pack("<i3d", k + 1, *POINTS[k]) for k in range(4)) + b"\n$EndNodes\n$Elements\n1\n"
             + struct.pack("<3i", 3, 10**9, 2) + struct.pack("<7i", 1, 0, 0, 1, 2, 3, 4) + b"\n$EndElements\n"),
        "m.msh: its $Elements section: element block 1 declares 1,000,000,000 elements, more than the 1 its section "
        "declares"),
}
# where the machine has the memory, these load (meshio's tag table: 8 bytes a tag up to 10⁸); in
# the capped subprocess alone they are refused, by the estimate, before meshio allocates the table
GMSH_CAPPED = {
    "MSH4 binary node tag 1e8 under a header of 4": (
        _msh(lambda: HEAD_BINARY + binary_nodes(4, tags=(1, 2, 3, 10**8)) + binary_elements(1, nodes=(1, 2, 3, 10**8))),
        "m.msh: declares 4 nodes and 0 elements (its $Nodes, with node tags up to 100,000,000 in entity block 1), "
        "which need"),
    "MSH2 ASCII node tag 1e9": (
        _msh("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 10 0 0\n3 10 10 0\n1000000000 0 10 0\n"
             "$EndNodes\n$Elements\n1\n1 3 2 0 1 1 2 3 1000000000\n$EndElements\n"),
        "m.msh: declares 4 nodes and 0 elements (its $Nodes, with node tags up to 1,000,000,000 in its $Nodes "
        "section), which need"),
}


# ---- XDMF time series, written by meshio, then edited ------------------------------------------------

def xdmf(d: Path, steps: int = 2, u_rows: int = 6, name: str = "ts.xdmf") -> Path:
    """A two-quad XDMF time series (HDF5 data): nodal vector 'u' and cell scalar 'c' at each time."""
    import os
    cwd = os.getcwd()
    os.chdir(d)                      # meshio's writer puts the .h5 file in the working directory
    try:
        with meshio.xdmf.TimeSeriesWriter(name) as w:
            w.write_points_cells(POINTS, [("quad", QUADS)])
            for t in range(steps):
                w.write_data(float(t), point_data={"u": np.full((u_rows, 3), 0.1 * t)},
                             cell_data={"c": [np.array([1.0, 2.0])]})
    finally:
        os.chdir(cwd)
    return d / name


def edit(path: Path, old: str, new: str) -> Path:
    text = path.read_text()
    assert text.count(old) >= 1, (old, text)
    return write(path, text.replace(old, new, 1))


def h5_replace(path: Path, key: str, data=None, shape=None) -> None:
    """Replace the dataset ``key`` of the .h5 beside ``path`` by ``data``, or by an unwritten one of ``shape``."""
    with h5py.File(path.with_suffix(".h5"), "a") as f:
        dtype = f[key].dtype
        del f[key]
        if data is not None:
            f.create_dataset(key, data=np.asarray(data, dtype))
        else:
            f.create_dataset(key, shape=shape, dtype=dtype)           # no storage: all fill value


def _xdmf(prepare):
    def case(d: Path):
        path = xdmf(d)
        prepare(path)
        return render(d, path.name, 'displacement = "u"\n')
    return case


def _geometry_dims(dims):
    return lambda p: edit(p, 'Dimensions="6 3" Format="HDF" Precision="8">ts.h5:/data0',
                          f'Dimensions="{dims}" Format="HDF" Precision="8">ts.h5:/data0')


XDMF = {
    "XDMF Geometry Dimensions 1e12": (
        _xdmf(_geometry_dims("1000000000000 3")),
        "ts.xdmf: Grid 'mesh': Geometry declares Dimensions '1000000000000 3' (3,000,000,000,000 values of 8 bytes), "
        "which need about"),
    "XDMF Attribute Dimensions 1e12": (
        _xdmf(lambda p: edit(p, 'Dimensions="6 3" Format="HDF" Precision="8">ts.h5:/data2',
                             'Dimensions="1000000000000 3" Format="HDF" Precision="8">ts.h5:/data2')),
        "ts.xdmf: time step 0, Attribute 'u' declares Dimensions '1000000000000 3' (3,000,000,000,000 values of 8 "
        "bytes), which need about"),
    "XDMF Geometry Dimensions unlike its dataset": (
        _xdmf(_geometry_dims("7 3")),
        "ts.xdmf: Grid 'mesh': Geometry declares Dimensions '7 3' (21 values), but ts.h5:/data0 holds (6, 3) (18 "
        "values)"),
    "XDMF XML Geometry of 1e8 nodes in 5 characters": (
        _xdmf(lambda p: edit(p, '<DataItem DataType="Float" Dimensions="6 3" Format="HDF" Precision="8">ts.h5:/data0',
                             '<DataItem DataType="Float" Dimensions="100000000 3" Format="XML" Precision="8">0 0 0')),
        "ts.xdmf: Grid 'mesh': Geometry declares Dimensions '100000000 3' (300,000,000 values"),
    "XDMF Topology indexing past its nodes": (
        _xdmf(lambda p: h5_replace(p, "data1", [[0, 1, 2, 3], [1, 4, 5, 99]])),
        "ts.xdmf: Topology: quad element 2 refers to node 100 (1-based position), outside the file's 6 nodes"),
    "XDMF nodal Attribute of 5 rows on 6 nodes": (
        _xdmf(lambda p: (edit(p, 'Dimensions="6 3" Format="HDF" Precision="8">ts.h5:/data2',
                              'Dimensions="5 3" Format="HDF" Precision="8">ts.h5:/data2'),
                         h5_replace(p, "data2", np.zeros((5, 3))))),
        "ts.xdmf: time step 0, Attribute 'u' (Center 'Node') declares Dimensions '5 3', but the mesh has 6 nodes "
        "(Grid 'mesh': Geometry)"),
    "XDMF Binary DataItem naming /dev/zero": (
        _xdmf(lambda p: edit(p, 'Format="HDF" Precision="8">ts.h5:/data2', 'Format="Binary" Precision="8">/dev/zero')),
        "ts.xdmf: time step 0, Attribute 'u' names the binary file /dev/zero, which a character device, not a file"),
}
XDMF_CAPPED = {
    "XDMF Geometry of 1e8 nodes in an unwritten dataset": (
        _xdmf(lambda p: (_geometry_dims("100000000 3")(p), h5_replace(p, "data0", shape=(10**8, 3)))),
        "ts.xdmf: Grid 'mesh': Geometry declares Dimensions '100000000 3' (300,000,000 values of 8 bytes), which "
        "need about 2.24 GiB"),
}
CASES = {**GMSH, **XDMF}


@pytest.mark.parametrize("name", list(CASES))
def test_a_hostile_mesh_is_refused_by_name_writing_nothing(tmp_path, capsys, name):
    d = tmp_path / "in"
    d.mkdir()
    argv = CASES[name][0](d)
    before = files(d)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert CASES[name][1] in err, err
    assert "Traceback" not in err and " — " in err            # the fix follows the problem
    assert files(d) == before and not (d / "out").exists()


@pytest.mark.process
def test_every_case_is_refused_under_a_500_MB_address_space_limit(tmp_path):
    cases = {**CASES, **GMSH_CAPPED, **XDMF_CAPPED}
    argvs = []
    for i, (make, _) in enumerate(cases.values()):
        d = tmp_path / f"c{i}"
        d.mkdir()
        argvs.append(make(d))
    for (name, (_, culprit)), (rc, err) in zip(cases.items(), main_under_cap(argvs)):
        assert rc == 2 and culprit in err and "Traceback" not in err, (name, rc, err)


# ---- honest files load as meshio reads them -----------------------------------------------------------

def _same_mesh(mesh, raw) -> None:
    """glsim's mesh from a file against meshio's reading of it: the nodes, and the quads by their nodes."""
    np.testing.assert_array_equal(mesh.nodes, np.asarray(raw.points, float))
    np.testing.assert_array_equal(mesh.quads, np.concatenate([b.data for b in raw.cells if b.type == "quad"]))


@pytest.mark.parametrize("version", ["2.2", "4.0", "4.1"])
@pytest.mark.parametrize("binary", [False, True])
def test_healthy_gmsh_files_load_as_meshio_reads_them(tmp_path, version, binary):
    from meshio.gmsh import _gmsh40
    path = tmp_path / "m.msh"
    mesh = meshio.Mesh(POINTS, [("quad", QUADS)])
    if version == "4.0":
        _gmsh40.write(path, mesh, binary=binary)
    else:
        meshio.write(path, mesh, file_format="gmsh22" if version == "2.2" else "gmsh", binary=binary)
    assert path.read_bytes().split(b"\n")[1].split()[:2] == [version.encode(), b"1" if binary else b"0"]
    _same_mesh(load_mesh(path), meshio.read(path))
    np.testing.assert_array_equal(load_mesh(path).nodes, POINTS)


def test_a_crafted_healthy_msh4_file_with_every_section_loads(tmp_path):
    """$Entities, two node blocks with sparse tags, $NodeData and $Periodic: walked, and read by meshio."""
    text = (HEAD_ASCII + "$Entities\n1 0 1 0\n1 0 0 0 1 7 \n1 0 0 0 20 10 0 0 0\n$EndEntities\n"
            "$Nodes\n2 6 1 60\n2 1 0 4\n1\n2\n3\n4\n0 0 0\n10 0 0\n10 10 0\n0 10 0\n2 1 0 2\n50\n60\n20 0 0\n20 10 0\n"
            "$EndNodes\n$Elements\n1 2 1 2\n2 1 3 2\n1 1 2 3 4\n2 2 50 60 3\n$EndElements\n"
            "$Periodic\n1\n1 1 1\n0\n1\n1 2\n$EndPeriodic\n"
            '$NodeData\n1\n"u"\n1\n0.0\n3\n0\n1\n6\n1 0.5\n2 0.5\n3 0.5\n4 0.5\n50 0.5\n60 0.5\n$EndNodeData\n')
    path = write(tmp_path / "m.msh", text)
    check_mesh_file(path)
    mesh = load_mesh(path)
    np.testing.assert_array_equal(mesh.nodes, POINTS)
    np.testing.assert_array_equal(mesh.quads, QUADS)


def test_healthy_xdmf_series_loads_as_written(tmp_path):
    path = xdmf(tmp_path, steps=3)
    with open_series(path) as s:
        np.testing.assert_array_equal(s.points, POINTS)
        np.testing.assert_array_equal(s.cells[0][1], QUADS)
        assert s.fields == {"u": 3} and list(s.times) == [0.0, 1.0, 2.0]
        np.testing.assert_array_equal(s.read("u", 2), np.full((6, 3), 0.2))


def test_a_single_state_xdmf_is_bounded_too(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    meshio.write("one.xdmf", meshio.Mesh(POINTS, [("quad", QUADS)], point_data={"u": POINTS * 0.01}))
    _same_mesh(load_mesh(tmp_path / "one.xdmf"), meshio.read("one.xdmf"))
    edit(tmp_path / "one.xdmf", 'Dimensions="6 3" Format="HDF" Precision="8">one.h5:/data0',
         'Dimensions="1000000000000 3" Format="HDF" Precision="8">one.h5:/data0')
    with pytest.raises(SceneError, match=r"one.xdmf: Grid 'Grid': Geometry declares Dimensions '1000000000000 3'"):
        load_mesh(tmp_path / "one.xdmf")
