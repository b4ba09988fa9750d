"""glsim.scene.mesh (and glsim.io.fe): shape functions, file round trips, solid boundaries, rejections, generators."""
import itertools

import meshio
import numpy as np
import pytest

from glsim.errors import SceneError
from glsim.io.fe import load_mesh
from glsim.scene.bilinear import bilinear as interpolate, shape_functions
from glsim.scene.mesh import (Mesh, bulge, bulge_displacements, disc, place, place_mesh, plate, quad_normals,
                              with_displacements)

RNG = np.random.default_rng(7)
GAUSS = np.array([-1, 1]) / np.sqrt(3)


# --- shape functions --------------------------------------------------------------------

def test_shape_functions_partition_of_unity_and_nodal_values():
    xi, eta = RNG.uniform(-1, 1, (2, 50))
    assert np.allclose(shape_functions(xi, eta).sum(axis=-1), 1.0)
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
    assert np.allclose(shape_functions(corners[:, 0], corners[:, 1]), np.eye(4))
    values = RNG.normal(size=(4, 2))
    assert np.allclose(interpolate(values, corners[:, 0], corners[:, 1]), values)


def test_collapsed_quad_is_a_linear_triangle():
    a, b, c = RNG.normal(size=(3, 3))
    corners = np.array([a, b, c, c])
    xi, eta = RNG.uniform(-1, 1, (2, 20))
    x = interpolate(corners, xi, eta)
    # barycentric coordinates of the mapped points
    lam_bc = np.linalg.lstsq(np.stack([b - a, c - a], axis=1), (x - a).T, rcond=None)[0].T
    lam = np.column_stack([1 - lam_bc.sum(axis=1), lam_bc])
    phi = shape_functions(xi, eta)
    assert np.allclose(lam, np.column_stack([phi[:, 0], phi[:, 1], phi[:, 2] + phi[:, 3]]))
    A, t = RNG.normal(size=(2, 3)), RNG.normal(size=2)
    affine = corners @ A.T + t
    assert np.allclose(interpolate(affine, xi, eta), x @ A.T + t)


# --- Mesh -------------------------------------------------------------------------------

def test_mesh_is_read_only_and_validated():
    m = plate(2.0, 1.0, 2, 1)
    assert m.n_steps == 1 and not m.nodes.flags.writeable and not m.displacements[0].flags.writeable
    m2 = with_displacements(m, [np.ones((m.n_nodes, 3))])
    assert m2.n_steps == 2 and np.allclose(m2.deformed(1), m.nodes + 1) and np.allclose(m2.deformed(0), m.nodes)
    with pytest.raises(SceneError, match="mesh.quads"):
        Mesh(m.nodes, m.quads + 10, m.node_labels, m.element_labels)
    with pytest.raises(SceneError, match=r"displacements\[0\].*zeros"):
        Mesh(m.nodes, m.quads, m.node_labels, m.element_labels, (np.ones((m.n_nodes, 3)),))
    with pytest.raises(SceneError, match="mesh.nodes.*not finite"):
        Mesh(np.full_like(m.nodes, np.nan), m.quads, m.node_labels, m.element_labels)
    with pytest.raises(SceneError, match="step"):
        m2.deformed(2)


# --- files ------------------------------------------------------------------------------

INP = """*HEADING
test
*NODE
101, 0.0, 0.0, 0.0
205, 1.0, 0.0, 0.0
303, 2.0, 0.0, 0.0
404, 0.0, 1.0, 0.0
517, 1.0, 1.0, 0.0
626, 2.0, 1.0, 0.0
777, 1.0, 2.0, 0.0
*ELEMENT, TYPE=S4R, ELSET=SHELL
11, 101, 205, 517, 404
12, 205, 303, 626, 517
*ELEMENT, TYPE=S3, ELSET=TRI
40, 517, 626, 777
"""


def test_abaqus_labels_and_csv_by_label(tmp_path):
    inp = tmp_path / "plate.inp"
    inp.write_text(INP)
    labels = [101, 205, 303, 404, 517, 626, 777]
    csv = tmp_path / "u1.csv"
    # shuffled order, ',' separator and a header line: each node gets ux = its label
    csv.write_text("label,ux,uy,uz\n" + "".join(f"{lab},{lab},{-lab},0.5\n" for lab in labels[::-1]))
    csv2 = tmp_path / "u2.csv"
    csv2.write_text("".join(f"{lab};{2 * lab};0;0\n" for lab in labels))
    m = load_mesh(inp, csv_files=[csv, csv2])
    assert m.node_labels.tolist() == labels
    assert m.element_labels.tolist() == [11, 12, 40]
    assert m.quads[2].tolist() == [4, 5, 6, 6]  # the triangle, collapsed
    assert m.n_steps == 3 and np.all(m.displacements[0] == 0)
    assert np.allclose(m.displacements[1][:, 0], m.node_labels) and np.allclose(m.displacements[1][:, 1], -m.node_labels)
    assert np.allclose(m.displacements[2][:, 0], 2 * m.node_labels)
    # node 517 sits at (1, 1)
    assert np.allclose(m.nodes[labels.index(517)], [1, 1, 0])


def test_abaqus_2d_nodes(tmp_path):
    inp = tmp_path / "flat.inp"
    inp.write_text("*NODE\n7, 0., 0.\n8, 3., 0.\n9, 3., 2.\n10, 0., 2.\n*ELEMENT, TYPE=CPS4\n1, 7, 8, 9, 10\n")
    m = load_mesh(inp)
    assert m.nodes.shape == (4, 3) and np.all(m.nodes[:, 2] == 0)
    assert m.node_labels.tolist() == [7, 8, 9, 10]


def _square_grid(n=2):
    """(n+1)² nodes of the unit square at z = 0 and its n² quads."""
    m = plate(1.0, 1.0, n, n, center=(0.5, 0.5, 0.0))
    return np.array(m.nodes), np.array(m.quads)


def test_vtu_point_data_steps(tmp_path):
    pts, quads = _square_grid()
    u1, u2 = RNG.normal(size=(len(pts), 3)), RNG.normal(size=(len(pts), 3))
    path = tmp_path / "m.vtu"
    meshio.write(path, meshio.Mesh(pts, [("quad", quads)], point_data={"U1": u1, "U2": u2, "T": pts[:, 0]}))
    m = load_mesh(path, point_data_steps=["U1", "U2"])
    assert m.n_steps == 3
    assert np.allclose(m.nodes, pts) and np.array_equal(m.quads, quads)
    assert np.allclose(m.displacements[1], u1)
    assert np.allclose(m.displacements[2], u2)   # 2-component arrays: tests/test_messages.py
    assert m.node_labels.tolist() == list(range(1, len(pts) + 1))


def test_gmsh_triangles_and_ignored_lines(tmp_path):
    pts, quads = _square_grid(1)
    tris = np.array([[0, 1, 3], [0, 3, 2]])
    lines = np.array([[0, 1], [1, 3]])
    tags = {k: [np.ones(2, dtype=int), np.ones(2, dtype=int)] for k in ("gmsh:physical", "gmsh:geometrical")}
    path = tmp_path / "m.msh"
    meshio.write(path, meshio.Mesh(pts, [("line", lines), ("triangle", tris)], cell_data=tags),
                 file_format="gmsh22", binary=False)
    m = load_mesh(path)
    assert m.quads.tolist() == [[0, 1, 3, 3], [0, 3, 2, 2]]
    assert m.element_labels.tolist() == [3, 4]  # position in the file; the lines come first
    assert np.isclose(0.5 * quad_normals(m.nodes, m.quads)[:, 2].sum(), 1.0)


def test_one_file_per_step(tmp_path):
    pts, quads = _square_grid()
    base = tmp_path / "m.vtu"
    meshio.write(base, meshio.Mesh(pts, [("quad", quads)]))
    truth, files = [], []
    for k in range(2):
        u = RNG.normal(size=(len(pts), 3))
        truth.append(u)
        files.append(tmp_path / f"step{k}.vtu")
        meshio.write(files[-1], meshio.Mesh(pts, [("quad", quads)], point_data={"disp": u, "eps": u[:, :1]}))
    m = load_mesh(base, displacement_files=files)
    assert all(np.allclose(m.displacements[k + 1], truth[k]) for k in range(2))
    two = tmp_path / "two.vtu"
    meshio.write(two, meshio.Mesh(pts, [("quad", quads)], point_data={"a": truth[0], "b": truth[1]}))
    with pytest.raises(SceneError, match="two.vtu.*set field"):
        load_mesh(base, displacement_files=[two])
    assert np.allclose(load_mesh(base, displacement_files=[two], field="b").displacements[1], truth[1])


# --- solids -----------------------------------------------------------------------------

def _block(nx, ny, nz):
    """Unit-cube grid nodes (index i + (nx+1)(j + (ny+1)k)) and an index function."""
    g = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), np.arange(nz + 1), indexing="ij"), -1)
    pts = g.transpose(2, 1, 0, 3).reshape(-1, 3).astype(float)
    return pts, lambda i, j, k: i + (nx + 1) * (j + (ny + 1) * k)


def _hexes(nx, ny, nz):
    pts, idx = _block(nx, ny, nz)
    cells = [[idx(i + di, j + dj, k + dk) for dk in (0, 1) for di, dj in ((0, 0), (1, 0), (1, 1), (0, 1))]
             for i, j, k in itertools.product(range(nx), range(ny), range(nz))]
    return pts, np.array(cells)


def _tets(nx, ny, nz):
    """Kuhn (Freudenthal) split: 6 tets per cube, conforming across cubes."""
    pts, idx = _block(nx, ny, nz)
    cells = []
    for i, j, k in itertools.product(range(nx), range(ny), range(nz)):
        for perm in itertools.permutations(range(3)):
            v, tet = np.array([i, j, k]), [idx(i, j, k)]
            for axis in perm:
                v[axis] += 1
                tet.append(idx(*v))
            cells.append(tet)
    return pts, np.array(cells)


def _assert_closed_outward(m, n_faces, area):
    assert m.n_elements == n_faces
    normals = quad_normals(m.nodes, m.quads)
    assert np.isclose(0.5 * np.linalg.norm(normals, axis=1).sum(), area)
    outward = m.nodes[m.quads].mean(axis=1) - m.nodes.mean(axis=0)
    assert np.all(np.einsum("ij,ij->i", normals, outward) > 0)


def test_hexahedron_boundary_faces_point_outwards(tmp_path):
    pts, hexes = _hexes(2, 2, 1)
    hexes[0] = hexes[0][[4, 5, 6, 7, 0, 1, 2, 3]]  # one element with mirrored node order
    path = tmp_path / "block.vtu"
    meshio.write(path, meshio.Mesh(pts, [("hexahedron", hexes)]))
    m = load_mesh(path)
    # 2×2 top + 2×2 bottom + 4 sides of 2×1
    _assert_closed_outward(m, 2 * 4 + 4 * 2, area=2 * 4 + 4 * 2)
    # each face's label is its parent hex's
    for quad, label in zip(m.quads, m.element_labels):
        assert set(quad) <= set(hexes[label - 1])


def test_abaqus_hex_labels(tmp_path):
    pts, hexes = _hexes(2, 1, 1)
    nodes = "".join(f"{i + 1}, {x}, {y}, {z}\n" for i, (x, y, z) in enumerate(pts))
    elements = "".join(f"{100 + e}, " + ", ".join(str(n + 1) for n in h) + "\n" for e, h in enumerate(hexes))
    path = tmp_path / "hex.inp"
    path.write_text(f"*NODE\n{nodes}*ELEMENT, TYPE=C3D8R\n{elements}")
    m = load_mesh(path)
    assert m.n_elements == 10 and sorted(set(m.element_labels.tolist())) == [100, 101]
    assert np.count_nonzero(m.element_labels == 100) == 5


def test_tetra_boundary_triangles(tmp_path):
    pts, tets = _tets(2, 2, 1)
    tets[::2] = tets[::2, [1, 0, 2, 3]]  # half of them with mirrored node order
    path = tmp_path / "tets.vtk"
    meshio.write(path, meshio.Mesh(pts, [("tetra", tets)]))
    m = load_mesh(path)
    assert np.all(m.quads[:, 2] == m.quads[:, 3])
    _assert_closed_outward(m, 2 * 16, area=16)


# --- rejections -------------------------------------------------------------------------

def _csv_case(tmp_path, text):
    inp = tmp_path / "plate.inp"
    inp.write_text(INP)
    csv = tmp_path / "u.csv"
    csv.write_text(text)
    return inp, csv


def test_rejects_unsupported_elements(tmp_path):
    pts = RNG.normal(size=(6, 3))
    path = tmp_path / "w6.vtu"
    meshio.write(path, meshio.Mesh(pts, [("wedge", np.arange(6)[None])]))
    with pytest.raises(SceneError, match="w6.vtu.*'wedge' is not supported.*quad/triangle shells") as err:
        load_mesh(path)
    assert err.value.key == str(path)


def test_rejects_missing_files(tmp_path):
    with pytest.raises(SceneError, match="nope.inp: file not found.*check the path"):
        load_mesh(tmp_path / "nope.inp")
    inp, _ = _csv_case(tmp_path, "")
    with pytest.raises(SceneError, match="gone.csv: file not found"):
        load_mesh(inp, csv_files=[tmp_path / "gone.csv"])


@pytest.mark.parametrize("text, match", [
    ("101;0;0;0\n999;1;2;3\n", r"u.csv:2: node label 999 is not in the mesh.*node labels"),
    ("101;0;0;0\n205;0;0;0\n", r"u.csv: 5 mesh nodes have no displacement \(labels 303, 404, 517, 626, 777\)"
                               r".*one line per mesh node"),
    ("label;ux;uy;uz\n101;0;x;0\n", r"u.csv:2: .* is not numeric.*label;ux;uy;uz"),
    ("101;0;0\n", r"u.csv:1: 3 fields instead of 4"),
])
def test_rejects_bad_csv(tmp_path, text, match):
    inp, csv = _csv_case(tmp_path, text)
    with pytest.raises(SceneError, match=match):
        load_mesh(inp, csv_files=[csv])


def test_rejects_bad_unit_and_point_data_name(tmp_path):
    pts, quads = _square_grid()
    path = tmp_path / "m.vtu"
    meshio.write(path, meshio.Mesh(pts, [("quad", quads)], point_data={"U": pts}))
    with pytest.raises(SceneError, match="specimen.unit: unknown unit 'mile'.*mm, m, cm, um, in"):
        load_mesh(path, unit="mile")
    with pytest.raises(SceneError, match=r"m.vtu: has no point-data array 'U9' .*it has: U .*specimen.mesh.point_data"):
        load_mesh(path, point_data_steps=["U9"])


def test_rejects_files_without_surface_cells(tmp_path):
    path = tmp_path / "lines.vtu"
    meshio.write(path, meshio.Mesh(RNG.normal(size=(3, 3)), [("line", np.array([[0, 1], [1, 2]]))]))
    with pytest.raises(SceneError, match="lines.vtu: has no quad"):
        load_mesh(path)


# --- units and placement ----------------------------------------------------------------

def test_units_and_rigid_placement(tmp_path):
    pts, quads = _square_grid()
    u = RNG.normal(size=(len(pts), 3))
    path = tmp_path / "m.vtu"
    meshio.write(path, meshio.Mesh(pts, [("quad", quads)], point_data={"U": u}))
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    t = np.array([10.0, -5.0, 200.0])
    m = load_mesh(path, unit="m", R=R, t=t, point_data_steps=["U"])
    assert np.allclose(m.nodes, 1000 * pts @ R.T + t)
    assert np.allclose(m.displacements[1], 1000 * u @ R.T)
    assert np.allclose(place([1.0, 2.0, 3.0], "in"), [25.4, 50.8, 76.2])
    assert np.allclose(place_mesh(plate(1, 1, 1, 1), "um").nodes[:, :2].max(axis=0), 5e-4)
    with pytest.raises(SceneError, match="specimen.R.*rotation"):
        place(pts, "mm", R=2 * R)


# --- generators -------------------------------------------------------------------------

def _min_angle_deg(m):
    x = m.nodes[m.quads]
    a, b = np.roll(x, 1, axis=1) - x, np.roll(x, -1, axis=1) - x
    cos = np.einsum("ijk,ijk->ij", a, b) / np.linalg.norm(a, axis=2) / np.linalg.norm(b, axis=2)
    return np.degrees(np.arccos(cos)).min()


def _min_jacobian(m):
    """Smallest 2×2 Jacobian determinant (in xy) over the 4 Gauss points of every quad."""
    xi, eta = (g.ravel() for g in np.meshgrid(GAUSS, GAUSS))
    dxi = 0.25 * np.stack([-(1 - eta), (1 - eta), (1 + eta), -(1 + eta)], -1)  # dΦ/dξ (4 points, 4 nodes)
    deta = 0.25 * np.stack([-(1 - xi), -(1 + xi), (1 + xi), (1 - xi)], -1)
    xy = m.nodes[m.quads][:, :, :2]
    jx, jy = np.einsum("pk,mkd->mpd", dxi, xy), np.einsum("pk,mkd->mpd", deta, xy)
    return (jx[..., 0] * jy[..., 1] - jx[..., 1] * jy[..., 0]).min()


def test_plate():
    m = plate(40.0, 20.0, 4, 2, center=(1.0, 2.0, 3.0))
    assert (m.n_nodes, m.n_elements) == (15, 8) and m.node_labels.tolist() == list(range(1, 16))
    normals = quad_normals(m.nodes, m.quads)
    assert np.isclose(0.5 * normals[:, 2].sum(), 800.0) and np.all(normals[:, 2] > 0)
    assert np.allclose(m.nodes.mean(axis=0), [1, 2, 3])
    with pytest.raises(SceneError, match="specimen.nx"):
        plate(1, 1, 0, 1)


@pytest.mark.parametrize("n_core, n_ring", [(8, 8), (4, 12), (16, 4), (1, 1)])
def test_disc_is_well_shaped(n_core, n_ring):
    m = disc(50.0, n_core, n_ring)
    assert m.n_elements == n_core ** 2 + 4 * n_core * n_ring
    assert np.allclose(np.linalg.norm(m.nodes[:, :2], axis=1).max(), 50.0) and np.all(m.nodes[:, 2] == 0)
    assert _min_jacobian(m) > 0 and _min_angle_deg(m) > 30


def test_disc_area():
    m = disc(50.0, 16, 16)
    assert abs(0.5 * quad_normals(m.nodes, m.quads)[:, 2].sum() / (np.pi * 50.0 ** 2) - 1) < 0.005


def test_bulge_field():
    R, t, w0 = 50.0, 3.0, 5.0
    m = bulge(R, t, w0, n_steps=4)
    assert m.n_steps == 5 and np.all(m.displacements[0] == 0)
    r = np.linalg.norm(m.nodes[:, :2], axis=1)
    centre, rim = np.flatnonzero(r < 1e-12), r > R - 1e-9
    assert len(centre) == 1 and rim.sum() == 4 * 8
    assert np.allclose(m.displacements[4][centre], [0, 0, -w0])
    assert np.allclose(m.displacements[2][centre], [0, 0, -w0 / 2])
    assert np.allclose(m.displacements[4][rim], 0, atol=1e-12)

    def w(rr):
        return w0 * (1 - rr ** 2 / R ** 2) ** 2

    h = 1e-5
    for radius in (10.0, 25.0, 40.0):
        node = np.array([[radius * np.cos(1.0), radius * np.sin(1.0), 0.0]])
        u = bulge_displacements(node, R, w0, 1, t)[0][0]
        u_r = u[:2] @ node[0, :2] / radius
        assert np.isclose(u[2], -w(radius))
        assert np.isclose(u_r, -(t / 2) * (w(radius + h) - w(radius - h)) / (2 * h), rtol=1e-6)
        assert u_r > 0 and abs(u[:2] @ [-np.sin(1.0), np.cos(1.0)]) < 1e-12  # radial, outwards
    up = bulge_displacements(m.nodes, R, w0, 1, t, direction=(0, 0, 2))[0]
    assert np.allclose(up[:, 2], -m.displacements[4][:, 2]) and np.allclose(up[:, :2], m.displacements[4][:, :2])
