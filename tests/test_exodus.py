"""FE time series (issue 20): Exodus II through netCDF4, ParaView .pvd collections and XDMF time
series, one load step per stored time.

The Exodus files are written here with netCDF4 following the Exodus II layout (not with the
reader's code); each step's rendered truth (X_deformed − X_undeformed at covered pixels) is
compared with the displacement written to the file, interpolated at the pixel's (element, ξ, η)
by the file's own node numbers.
"""
import dataclasses
import importlib.util
import os
from pathlib import Path

import meshio
import numpy as np
import pytest

netCDF4 = pytest.importorskip("netCDF4")

from glsim.errors import SceneError  # noqa: E402
from glsim.io.fe import load_series  # noqa: E402
from glsim.render import Renderer  # noqa: E402
from glsim.scene.bilinear import shape_functions  # noqa: E402
from glsim.scene.load import scene_from_dict  # noqa: E402
from glsim.io.fe import specimen_mesh  # noqa: E402

RNG = np.random.default_rng(20)
DIST = 300.0       # mm from camera 0 (the world frame) to the specimen


# --- an Exodus II writer that follows the netCDF layout --------------------------------------

def write_exodus(path, coords, blocks, times, fields, node_map=None, elem_map=None, combined=False,
                 fmt="NETCDF3_64BIT_OFFSET"):
    """coords (N, dim); blocks [(name, elem_type, conn 1-based (E, k))]; fields {name: (T, N)}.

    combined: coordinates as ``coord`` and nodal values as one ``vals_nod_var`` (time, var,
    node) instead of ``coordx…`` and ``vals_nod_var{j}``.
    """
    coords = np.asarray(coords, dtype=np.float64)
    n, dim = coords.shape
    n_elem = sum(len(b[2]) for b in blocks)
    with netCDF4.Dataset(path, "w", format=fmt) as ds:
        ds.title, ds.api_version, ds.version, ds.floating_point_word_size = "glsim test", 8.0, 8.0, 8
        for name, size in (("len_string", 33), ("len_name", 33), ("len_line", 81), ("four", 4),
                           ("time_step", None), ("num_dim", dim), ("num_nodes", n), ("num_elem", n_elem),
                           ("num_el_blk", len(blocks))):
            ds.createDimension(name, size)
        ds.createVariable("time_whole", "f8", ("time_step",))[:] = np.asarray(times, dtype=np.float64)
        eb_names = ds.createVariable("eb_names", "S1", ("num_el_blk", "len_name"))
        eb_names[:] = netCDF4.stringtochar(np.array([b[0] for b in blocks], dtype="S33"))
        prop = ds.createVariable("eb_prop1", "i4", ("num_el_blk",))
        prop.setncattr("name", "ID")
        prop[:] = np.arange(1, len(blocks) + 1) * 10
        for i, (_, elem_type, conn) in enumerate(blocks, 1):
            conn = np.asarray(conn)
            ds.createDimension(f"num_el_in_blk{i}", len(conn))
            ds.createDimension(f"num_nod_per_el{i}", conn.shape[1])
            var = ds.createVariable(f"connect{i}", "i4", (f"num_el_in_blk{i}", f"num_nod_per_el{i}"))
            var.elem_type = elem_type
            var[:] = conn
        if combined:
            ds.createVariable("coord", "f8", ("num_dim", "num_nodes"))[:] = coords.T
        else:
            for axis, name in enumerate(["coordx", "coordy", "coordz"][:dim]):
                ds.createVariable(name, "f8", ("num_nodes",))[:] = coords[:, axis]
        if node_map is not None:
            ds.createVariable("node_num_map", "i4", ("num_nodes",))[:] = node_map
        if elem_map is not None:
            ds.createVariable("elem_num_map", "i4", ("num_elem",))[:] = elem_map
        ds.createDimension("num_nod_var", len(fields))
        ds.createVariable("name_nod_var", "S1", ("num_nod_var", "len_name"))[:] = netCDF4.stringtochar(
            np.array(list(fields), dtype="S33"))
        values = [np.asarray(v, dtype=np.float64) for v in fields.values()]
        if combined:
            ds.createVariable("vals_nod_var", "f8", ("time_step", "num_nod_var", "num_nodes"))[:] = np.stack(values, 1)
        else:
            for j, v in enumerate(values, 1):
                ds.createVariable(f"vals_nod_var{j}", "f8", ("time_step", "num_nodes"))[:] = v
    return Path(path)


def grid(nx, ny, width, height):
    """Nodes (N,2) of a width × height grid centred at 0, and its node index (ny+1, nx+1)."""
    x, y = np.meshgrid(np.linspace(-width / 2, width / 2, nx + 1), np.linspace(-height / 2, height / 2, ny + 1))
    return np.stack([x.ravel(), y.ravel()], 1), np.arange(x.size).reshape(x.shape)


def field(xyz, t):
    """A smooth displacement (N,3) at time t (file units), zero at t = 0."""
    x, y, z = (xyz[:, i] if i < xyz.shape[1] else 0 * xyz[:, 0] for i in range(3))
    return t * np.stack([0.004 + 0.002 * x - 0.001 * y, -0.003 + 0.0015 * x * y / 4,
                         0.01 * np.cos(0.5 * x) + 0.002 * z], 1)


# --- the 2-D and 3-D cases ---------------------------------------------------------------------

TIMES_2D = [0.0, 50.0, 125.0, 200.0]


def plate_2d(tmp_path, combined=False, fmt="NETCDF3_64BIT_OFFSET", name="plate2d.e"):
    """A 4 × 3 cm plate in cm: QUAD4 block on the left half, TRI3 block on the right, shuffled node
    and element numbers, disp_x/disp_y (no z: a 2-D result) and a strain field at 4 times."""
    xy, idx = grid(6, 4, 4.0, 3.0)
    q = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1)   # (4, 6, 4) CCW
    quads = q[:, :3].reshape(-1, 4)
    right = q[:, 3:].reshape(-1, 4)
    tris = np.concatenate([right[:, [0, 1, 2]], right[:, [0, 2, 3]]])
    node_map = 1000 + 7 * RNG.permutation(len(xy))
    elem_map = 500 + 3 * RNG.permutation(len(quads) + len(tris))
    u = np.stack([field(xy, t / 100) for t in TIMES_2D])                           # (T, N, 3) cm
    fields = {"disp_x": u[..., 0], "disp_y": u[..., 1], "strain_xx": u[..., 0] * 0.1}
    path = write_exodus(tmp_path / name, xy, [("left", "QUAD4", quads + 1), ("right", "TRI3", tris + 1)],
                        TIMES_2D, fields, node_map, elem_map, combined=combined, fmt=fmt)
    written = {int(label): u[:, i] * np.array([1.0, 1.0, 0.0]) for i, label in enumerate(node_map)}
    return path, written


def hex_tet_3d(tmp_path):
    """A 40 × 30 × 4 mm slab in mm, coordinates as `coord`, values as one vals_nod_var: HEX8 block
    for x < 0 and a TETRA4 block (MOOSE's spelling) for x > 0 sharing the nodes at x = 0; times
    start at 10 with a non-zero displacement (so glsim puts an undeformed step 0 in front)."""
    nx, ny, nz = 4, 3, 1
    x, y, z = np.meshgrid(np.linspace(-20, 20, 2 * nx + 1), np.linspace(-15, 15, ny + 1),
                          np.linspace(-4, 0, nz + 1), indexing="ij")
    xyz = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    idx = np.arange(x.size).reshape(x.shape)
    hexes, tets = [], []
    for i in range(2 * nx):
        for j in range(ny):
            for k in range(nz):
                c = [idx[i, j, k], idx[i + 1, j, k], idx[i + 1, j + 1, k], idx[i, j + 1, k],
                     idx[i, j, k + 1], idx[i + 1, j, k + 1], idx[i + 1, j + 1, k + 1], idx[i, j + 1, k + 1]]
                if i < nx:
                    hexes.append(c)
                else:  # the Kuhn split of the cube into 6 positively oriented tets
                    for a, b in ((1, 2), (2, 3), (3, 7), (7, 4), (4, 5), (5, 1)):
                        tets.append([c[0], c[a], c[b], c[6]] if (a, b) in ((2, 3), (7, 4), (5, 1))
                                    else [c[0], c[b], c[a], c[6]])
    tets = np.array(tets)
    vol = np.einsum("ij,ij->i", np.cross(xyz[tets[:, 1]] - xyz[tets[:, 0]], xyz[tets[:, 2]] - xyz[tets[:, 0]]),
                    xyz[tets[:, 3]] - xyz[tets[:, 0]])
    tets[vol < 0] = tets[vol < 0][:, [0, 2, 1, 3]]
    times = [10.0, 20.0, 30.0]
    u = np.stack([field(xyz / 10, t / 10) * 10 for t in times])
    fields = {"disp_x": u[..., 0], "disp_y": u[..., 1], "disp_z": u[..., 2], "temperature": 0 * u[..., 0] + 300}
    node_map = np.arange(1, len(xyz) + 1) * 2
    path = write_exodus(tmp_path / "slab3d.exo", xyz, [("hexes", "HEX8", np.array(hexes) + 1),
                                                       ("tets", "TETRA4", tets + 1)],
                        times, fields, node_map=node_map, combined=True)
    return path, {int(label): u[:, i] for i, label in enumerate(node_map)}


def scene_for(path, size=(160, 120), fx=900.0, **mesh_keys):
    """One camera square onto the specimen, DIST mm away; the CPU oracle."""
    return scene_from_dict({
        "cameras": [{"size": list(size), "fx": fx, "fy": fx, "cx": (size[0] - 1) / 2, "cy": (size[1] - 1) / 2}],
        "specimen": {"mesh": {"path": str(path), **mesh_keys}, "pose": {"t": [0.0, 0.0, DIST]}},
        "speckle": {"dot_diameter_px": 4.0, "seed": 3},
        "render": {"backend": "cpu", "mode": "exact"},
    }, Path(path).parent)


def check_truth(scene, written, file_steps, scale, min_pixels=2000):
    """Render every load step; truth displacement = the written one at (element, ξ, η)."""
    with Renderer(scene, backend="cpu") as r:
        mesh = r.mesh
        labels = mesh.node_labels
        assert mesh.n_steps == len(file_steps)
        for step, k in enumerate(file_steps):
            tr = r.render(0, step, truth=True).truth
            m = tr.mask
            assert m.sum() >= min_pixels
            du = tr.X_deformed[m] - tr.X_undeformed[m]
            nodes = mesh.quads[tr.element[m]]                                        # (P, 4)
            u_nodes = (np.zeros((len(labels), 3)) if k is None else
                       np.stack([written[int(label)][k] for label in labels]) * scale)
            expected = np.einsum("pk,pkd->pd", shape_functions(tr.xi[m], tr.eta[m]), u_nodes[nodes])
            assert np.abs(du - expected).max() < 1e-9 * max(1.0, np.abs(expected).max()), (step, k)
    return mesh


# --- Exodus II -----------------------------------------------------------------------------

def test_exodus_2d_two_blocks_every_time_is_a_step_with_truth(tmp_path):
    path, written = plate_2d(tmp_path)
    scene = scene_for(path, unit="cm", displacement=["disp_x", "disp_y", "disp_z"])   # no disp_z in 2-D: 0
    mesh = check_truth(scene, written, [0, 1, 2, 3], scale=10.0)
    # t = 0 has zero displacement: it is step 0 and the k-th stored time is step k
    assert mesh.step_times == tuple(TIMES_2D)
    assert mesh.n_elements == 12 + 24 and set(mesh.element_labels) >= set(range(500, 500 + 3 * 36, 3))
    for k in range(4):   # the loaded nodal displacements, by the file's node numbers
        expected = np.stack([written[int(label)][k] for label in mesh.node_labels]) * 10.0
        assert np.allclose(mesh.displacements[k], expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("fmt", ["NETCDF3_CLASSIC", "NETCDF4"])
def test_exodus_2d_layouts_and_default_fields(tmp_path, fmt):
    path, written = plate_2d(tmp_path, combined=True, fmt=fmt)
    mesh = specimen_mesh(scene_for(path))           # disp_x / disp_y found by name, all times
    assert mesh.n_steps == 4 and mesh.step_times == tuple(TIMES_2D)
    u = np.stack([written[int(label)][3] for label in mesh.node_labels])
    assert np.allclose(mesh.displacements[3], u, atol=1e-12)
    assert np.allclose(mesh.nodes[:, 2], DIST)


@pytest.mark.filterwarnings("ignore:camera cam0.*grazing")   # the slab's sides, seen edge-on
def test_exodus_3d_hex_and_tetra4_blocks_with_truth(tmp_path):
    path, written = hex_tet_3d(tmp_path)
    scene = scene_for(path, fx=1000.0)
    # times 10, 20, 30 all deformed: undeformed step 0 (no time) in front
    mesh = check_truth(scene, written, [None, 0, 1, 2], scale=1.0, min_pixels=4000)
    assert mesh.step_times == (None, 10.0, 20.0, 30.0)
    assert set(mesh.node_labels.tolist()) == set(written)
    # only outer faces: the two blocks' faces at x = 0 are inner, seen by neither camera side
    x = mesh.nodes[mesh.quads][..., 0]
    interface = np.all(np.abs(x) < 1e-9, axis=1)
    assert interface.sum() == 3 + 6   # 3 hex quads + 6 tet triangles, coincident (inside the solid)


def test_exodus_select_times_and_steps(tmp_path):
    path, written = plate_2d(tmp_path)
    by_time = specimen_mesh(scene_for(path, times=[200.0, 50.0]))
    assert by_time.step_times == (None, 200.0, 50.0) and by_time.n_steps == 3
    label = int(by_time.node_labels[5])
    assert np.allclose(by_time.displacements[1][5], written[label][3])
    by_index = specimen_mesh(scene_for(path, steps=[0, 2, -1], unit="m"))
    assert by_index.step_times == (0.0, 125.0, 200.0)
    assert np.allclose(by_index.displacements[2][5], written[label][3] * 1000.0)
    assert np.allclose(by_index.nodes[:, :2] / 1000.0, by_time.nodes[:, :2])


def test_exodus_truth_of_selected_times(tmp_path):
    path, written = plate_2d(tmp_path)
    check_truth(scene_for(path, unit="cm", times=[125.0]), written, [None, 2], scale=10.0)


# --- malformed and mismatched files: file + field/time + what exists --------------------------

def test_missing_field_lists_fields_and_times(tmp_path):
    path, _ = plate_2d(tmp_path)
    with pytest.raises(SceneError) as e:
        specimen_mesh(scene_for(path, displacement=["ux", "uy"]))
    msg = str(e.value)
    assert "plate2d.e" in msg and "'ux'" in msg
    assert "fields in plate2d.e: disp_x, disp_y, strain_xx; times 0–200, 4 steps" in msg


def test_missing_time_and_step(tmp_path):
    path, _ = plate_2d(tmp_path)
    with pytest.raises(SceneError, match=r"plate2d\.e: has no time 100 \(nearest 125\); times 0–200, 4 steps"):
        specimen_mesh(scene_for(path, times=[100.0]))
    with pytest.raises(SceneError, match=r"plate2d\.e: has no stored step 4; times 0–200, 4 steps"):
        specimen_mesh(scene_for(path, steps=[4]))


def test_scalar_as_vector_and_vector_component_rejected(tmp_path):
    path, _ = plate_2d(tmp_path)
    with pytest.raises(SceneError, match="'strain_xx' is a scalar.*fields in plate2d.e"):
        specimen_mesh(scene_for(path, displacement="strain_xx"))
    path3, _ = hex_tet_3d(tmp_path)   # a 3-D file: a missing z component is an error, not zero
    with pytest.raises(SceneError, match=r"no nodal field 'uz' \(the z displacement\).*fields in slab3d.exo"):
        specimen_mesh(scene_for(path3, displacement=["disp_x", "disp_y", "uz"]))
    zero_z = specimen_mesh(scene_for(path3, displacement=["disp_x", "disp_y", ""]))
    assert not np.any(zero_z.displacements[2][:, 2])


def test_non_finite_values_name_the_time(tmp_path):
    xy, idx = grid(2, 1, 2.0, 1.0)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    ux = np.zeros((3, len(xy)))
    ux[1] = 0.1
    ux[2, 4] = np.nan
    path = write_exodus(tmp_path / "nan.e", xy, [("b", "QUAD", quads + 1)], [0.0, 1.0, 2.0],
                        {"disp_x": ux, "disp_y": ux * 0})
    with pytest.raises(SceneError, match=r"nan\.e: displacement disp_x/disp_y/0 has non-finite values at time 2 "
                                         r"\(stored step 2\) on 1 nodes \(labels 5\)"):
        load_series(path)
    assert load_series(path, times=[1.0]).n_steps == 2


@pytest.mark.parametrize("elem_type,nodes", [("TRI7", 7), ("TETRA14", 14), ("HEX21", 21), ("WEDGE20", 20),
                                             ("QUAD", 5)])
def test_unconfirmed_quadratic_elements_rejected_by_name(tmp_path, elem_type, nodes):
    """QUAD8/9, TRI6, TETRA10, HEX20, HEX27, WEDGE15 are read (tests/test_quadratic.py); other
    node counts are refused by name."""
    xy = RNG.uniform(size=(nodes, 2))
    path = write_exodus(tmp_path / "q.e", xy, [("plate", elem_type, np.arange(1, nodes + 1)[None])], [0.0],
                        {"disp_x": np.zeros((1, nodes)), "disp_y": np.zeros((1, nodes))})
    with pytest.raises(SceneError, match=rf"q\.e: element block 'plate' \(id 10\) has {elem_type} elements "
                                         rf"\({nodes} nodes each\): these quadratic elements are not supported"):
        load_series(path)


def test_linear_wedges_are_refused_by_name(tmp_path):
    xyz = RNG.uniform(size=(6, 3))
    path = write_exodus(tmp_path / "w.e", xyz, [("solid", "WEDGE6", np.arange(1, 7)[None])], [0.0],
                        {f"disp_{a}": np.zeros((1, 6)) for a in "xyz"})
    with pytest.raises(SceneError, match=r"w\.e: element block 'solid' \(id 10\) has WEDGE6 elements \(6 nodes "
                                         r"each\), which are not supported — use quad/triangle shells"):
        load_series(path)


def test_quadratic_element_with_a_missing_node(tmp_path):
    xy = RNG.uniform(size=(7, 2))
    path = write_exodus(tmp_path / "q.e", xy, [("plate", "QUAD8", np.arange(1, 8)[None])], [0.0],
                        {"disp_x": np.zeros((1, 7)), "disp_y": np.zeros((1, 7))})
    with pytest.raises(SceneError, match=r"q\.e: element block 'plate' \(id 10\) has QUAD8 elements with 7 nodes "
                                         r"each — a QUAD8 element needs 8 nodes \(a missing node\?\)"):
        load_series(path)


def test_not_exodus_files(tmp_path):
    text = tmp_path / "notes.e"
    text.write_text("not a netCDF file\n")
    with pytest.raises(SceneError, match=r"notes\.e: is not a netCDF file"):
        load_series(text)
    with netCDF4.Dataset(tmp_path / "other.e", "w") as ds:
        ds.createDimension("lat", 3)
    with pytest.raises(SceneError, match=r"other\.e: has no dimension 'num_nodes'.*dimensions: lat"):
        load_series(tmp_path / "other.e")
    with pytest.raises(SceneError, match=r"missing\.e: file not found"):
        load_series(tmp_path / "missing.e")


def test_scene_keys_are_checked(tmp_path):
    path, _ = plate_2d(tmp_path)
    (tmp_path / "m.inp").write_text("")
    with pytest.raises(SceneError, match="specimen.mesh.times: is only used with time-series files"):
        scene_for(tmp_path / "m.inp", times=[1.0])
    with pytest.raises(SceneError, match="specimen.mesh.point_data: is for single-state files"):
        scene_for(path, point_data=["disp_x"])
    with pytest.raises(SceneError, match="specimen.mesh.steps: times and steps both given"):
        scene_for(path, times=[0.0], steps=[1])
    with pytest.raises(SceneError, match="specimen.mesh.displacement"):
        scene_for(path, displacement=["a", "b", "c", "d"])
    with pytest.raises(SceneError, match=r"specimen.mesh.steps\[0\]: expected an integer"):
        scene_for(path, steps=[1.5])
    scene = scene_for(path, displacement="u", times=[0, 50])
    assert scene.specimen.mesh.displacement == ("u",) and scene.specimen.mesh.times == (0.0, 50.0)
    assert scene.to_dict()["specimen"]["mesh"]["displacement"] == ["u"]


# --- ParaView .pvd and XDMF time series ------------------------------------------------------------

def _tri_plate():
    xy, idx = grid(6, 4, 40.0, 30.0)
    q = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    points = np.pad(xy, ((0, 0), (0, 1)))
    return points, q


PVD_TIMES = [0.0, 0.25, 0.5]


def test_pvd_collection_one_step_per_time(tmp_path):
    points, quads = _tri_plate()
    entries, written = [], {}
    for k, t in enumerate(PVD_TIMES):
        u = field(points / 10, t) * 10
        meshio.write(tmp_path / f"plate_{k:03d}.vtu", meshio.Mesh(points, [("quad", quads)],
                                                                   point_data={"u": u, "T": u[:, 0]}))
        entries.append(f'<DataSet timestep="{t}" part="0" file="plate_{k:03d}.vtu"/>')
        for i in range(len(points)):
            written.setdefault(i + 1, []).append(u[i])
    (tmp_path / "plate.pvd").write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">'
                                        "<Collection>" + "".join(reversed(entries)) + "</Collection></VTKFile>\n")
    written = {k: np.array(v) for k, v in written.items()}
    mesh = check_truth(scene_for(tmp_path / "plate.pvd", displacement="u"), written, [0, 1, 2], scale=1.0)
    assert mesh.step_times == tuple(PVD_TIMES)       # sorted by time, whatever the file order
    assert specimen_mesh(scene_for(tmp_path / "plate.pvd")).n_steps == 3     # "u" found by name
    with pytest.raises(SceneError, match=r"plate\.pvd: has no time 0\.3 \(nearest 0\.25\); times 0–0\.5, 3 steps"):
        specimen_mesh(scene_for(tmp_path / "plate.pvd", times=[0.3]))
    with pytest.raises(SceneError, match=r"no nodal field 'disp'; fields in plate\.pvd: u, T; times 0–0\.5"):
        specimen_mesh(scene_for(tmp_path / "plate.pvd", displacement="disp"))
    (tmp_path / "plate_002.vtu").unlink()
    with pytest.raises(SceneError, match=r"plate\.pvd: lists plate_002\.vtu, which does not exist"):
        specimen_mesh(scene_for(tmp_path / "plate.pvd"))


def test_xdmf_time_series_one_step_per_time(tmp_path, monkeypatch):
    pytest.importorskip("h5py")
    monkeypatch.chdir(tmp_path)       # meshio's writer puts plate.h5 in the working directory
    points, quads = _tri_plate()
    times = [0.0, 1.0, 2.0, 3.0]
    written = {}
    with meshio.xdmf.TimeSeriesWriter(tmp_path / "plate.xdmf") as w:
        w.write_points_cells(points[:, :2], [("quad", quads)])
        for t in times:
            u = field(points / 10, t / 4) * 10
            w.write_data(t, point_data={"ux": u[:, 0].copy(), "uy": u[:, 1].copy(), "uz": u[:, 2].copy(),
                                        "u2": u[:, :2].copy()})
            for i in range(len(points)):
                written.setdefault(i + 1, []).append(u[i])
    written = {k: np.array(v) for k, v in written.items()}
    path = tmp_path / "plate.xdmf"
    mesh = check_truth(scene_for(path, displacement=["ux", "uy", "uz"], unit="mm"), written, [0, 1, 2, 3], 1.0)
    assert mesh.step_times == tuple(times)
    in_plane = specimen_mesh(scene_for(path, displacement="u2", steps=[-1]))   # a 2-component vector field
    label = int(in_plane.node_labels[7])
    assert np.allclose(in_plane.displacements[1][7], written[label][3] * [1, 1, 0])
    with pytest.raises(SceneError, match=r"plate\.xdmf: has no stored step 9; times 0–3, 4 steps"):
        specimen_mesh(scene_for(path, steps=[9]))


# --- pyvale's MOOSE outputs, where pyvale is installed -------------------------------------------

def _pyvale_exodus_dir():
    given = os.environ.get("GLSIM_PYVALE_DATA")   # …/pyvale/data/simulation/exodus, without installing it
    if given:
        return Path(given)
    spec = importlib.util.find_spec("pyvale")
    if spec is not None and spec.submodule_search_locations:
        return Path(list(spec.submodule_search_locations)[0]) / "data" / "simulation" / "exodus"
    verify_venv = sorted((Path(__file__).resolve().parent.parent / ".venv-verify").glob(   # `make verify`'s
        "lib/python*/site-packages/pyvale/data/simulation/exodus"))
    return verify_venv[0] if verify_venv else None


PYVALE = _pyvale_exodus_dir()


@pytest.mark.skipif(PYVALE is None or not PYVALE.is_dir(), reason="pyvale (its MOOSE outputs) not installed")
def test_pyvale_moose_outputs():
    with netCDF4.Dataset(PYVALE / "case18_out.e") as ds:      # 2-D plate in metres, 200 QUAD4, 41 times
        names = [n.strip() for n in netCDF4.chartostring(ds["name_nod_var"][:])]
        ux = np.asarray(ds[f"vals_nod_var{names.index('disp_x') + 1}"][:])
        uy = np.asarray(ds[f"vals_nod_var{names.index('disp_y') + 1}"][:])
        labels = np.asarray(ds["node_num_map"][:])
    mesh = load_series(PYVALE / "case18_out.e", unit="m")
    assert (mesh.n_nodes, mesh.n_elements, mesh.n_steps) == (231, 200, 41)
    assert mesh.step_times[0] == 0.0 and mesh.step_times[-1] == 200.0
    order = {int(label): i for i, label in enumerate(labels)}
    rows = [order[int(label)] for label in mesh.node_labels]
    for k in (1, 20, 40):
        assert np.allclose(mesh.displacements[k][:, 0], ux[k, rows] * 1000.0)
    # truth of rendered steps = the file's field (plate 100 × 50 mm from the origin, centred in view)
    written = {int(label): np.stack([ux[:, i], uy[:, i], 0 * ux[:, i]], 1) for i, label in enumerate(labels)}
    scene = scene_for(PYVALE / "case18_out.e", size=(320, 200), fx=780.0, unit="m", steps=[0, 20, 40],
                      displacement=["disp_x", "disp_y", "disp_z"]).replace(specimen={"t": (-50.0, -25.0, DIST)})
    assert check_truth(scene, written, [0, 20, 40], scale=1000.0, min_pixels=20000).step_times == (0.0, 100.0, 200.0)
    tet = load_series(PYVALE / "case26_out.e", unit="m", steps=[0, 10])   # TETRA4
    assert tet.n_steps == 2 and tet.step_times == (0.0, 10.0)
    from glsim.scene import quadratic as qd
    for name in ("case17_out.e", "case16_out.e", "case00_TET10_out.e"):   # QUAD9, HEX20, TETRA10: read now
        quad = load_series(PYVALE / name, unit="m")
        assert quad.is_quadratic and not qd.folded(qd.patch_points(quad.patches, quad.nodes)).any()


def test_sequence_writes_the_step_times(tmp_path):
    import json

    from glsim.workflows.sequence import write_sequence
    path, _ = plate_2d(tmp_path)
    scene = scene_for(path, size=(80, 60), fx=450.0, unit="cm", times=[125.0, 200.0])
    written = write_sequence(scene, tmp_path / "out")
    assert len(written.images) == 3                    # undeformed step 0, t = 125, t = 200
    steps = json.loads((tmp_path / "out" / "steps.json").read_text())["steps"]
    assert steps == [{"step": 0, "time": None}, {"step": 1, "time": 125.0}, {"step": 2, "time": 200.0}]


# --- examples/exodus ------------------------------------------------------------------------------

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "exodus"


def _example_module():
    spec = importlib.util.spec_from_file_location("make_exodus", EXAMPLE / "make_exodus.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_example_file_is_reproducible(tmp_path):
    fresh = _example_module().write(tmp_path / "plate_out.e")
    with netCDF4.Dataset(fresh) as a, netCDF4.Dataset(EXAMPLE / "plate_out.e") as b:
        assert set(a.variables) == set(b.variables) and set(a.dimensions) == set(b.dimensions)
        for name in a.variables:
            assert np.array_equal(a[name][:], b[name][:]), name


def test_example_scene_renders_the_file_displacement():
    from glsim.scene import load_scene

    module = _example_module()
    scene = load_scene(EXAMPLE / "scene.toml")
    written = {}
    xy, _, _ = module.mesh()
    for k, t in enumerate(module.TIMES):
        u = np.pad(module.displacement(xy, t), ((0, 0), (0, 1)))
        for i in range(len(xy)):
            written.setdefault(1001 + i, []).append(u[i])
    written = {label: np.array(v) for label, v in written.items()}
    mesh = check_truth(scene, written, [0, 5, 10], scale=1000.0, min_pixels=20000)
    assert mesh.step_times == (0.0, 50.0, 100.0)
    assert specimen_mesh(scene.replace(specimen={"mesh": dataclasses.replace(
        scene.specimen.mesh, times=())})).n_steps == 11


def test_load_mesh_reads_time_series_whole(tmp_path):
    from glsim.io.fe import load_mesh

    path, written = plate_2d(tmp_path)
    mesh = load_mesh(path, unit="cm")                     # not meshio's single state: every time
    assert mesh.n_steps == 4 and mesh.step_times == tuple(TIMES_2D)
    assert np.allclose(mesh.displacements[2][3], written[int(mesh.node_labels[3])][2] * 10.0)
    with pytest.raises(SceneError, match=r"plate2d\.e: holds its own time steps"):
        load_mesh(path, point_data_steps=["disp_x"])


def test_two_component_vector_only_on_a_plane_mesh(tmp_path):
    points, quads = _tri_plate()
    points[:, 2] = 0.1 * points[:, 0]                     # a tilted plate: which plane would 2 components be in?
    meshio.write(tmp_path / "tilted.vtu", meshio.Mesh(points, [("quad", quads)],
                                                      point_data={"u": np.ones((len(points), 2))}))
    (tmp_path / "tilted.pvd").write_text('<VTKFile type="Collection"><Collection>'
                                         '<DataSet timestep="1" file="tilted.vtu"/></Collection></VTKFile>')
    with pytest.raises(SceneError, match=r"tilted\.pvd: nodal field 'u' has 2 components per node on a mesh "
                                         r"that is not plane"):
        load_series(tmp_path / "tilted.pvd", displacement="u")


def test_default_fields_need_z_in_3d(tmp_path):
    cube = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    zeros = np.zeros((2, 8))
    path = write_exodus(tmp_path / "cube.e", cube, [("c", "HEX", np.arange(1, 9)[None])], [0.0, 1.0],
                        {"disp_x": zeros + [[0], [1]], "disp_y": zeros})
    with pytest.raises(SceneError, match=r"cube\.e: no displacement field found by name.*fields in cube\.e: "
                                         r"disp_x, disp_y; times 0–1, 2 steps"):
        load_series(path)
    mesh = load_series(path, displacement=["disp_x", "disp_y", ""])     # an explicit zero z
    assert mesh.n_steps == 2 and np.allclose(mesh.displacements[1], [1, 0, 0])
