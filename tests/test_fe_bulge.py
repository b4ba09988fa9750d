"""The FE bulge example (examples/fe_bulge/): a scikit-fem solution of the paper's Table 2 plate
(linear Kirchhoff plate, clamped, Argyris triangles) stored as Abaqus S3 triangles + per-step CSV
files, checked against linear plate theory and read back through glsim's ordinary mesh loader.

Only the regeneration test needs scikit-fem; the committed files load without it.
"""

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from glsim.io.fe import load_mesh
from glsim.scene.mesh import bulge_displacements
from glsim.io.fe import specimen_mesh
from glsim.render import render
from glsim.scene import load_scene

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
FE = EXAMPLES / "fe_bulge"

# Table 2 of the reference paper (mm, MPa), and linear Kirchhoff theory of the clamped plate.
R, T, E, NU, P = 50.0, 3.0, 210000.0, 0.3, 11.9
D = E * T ** 3 / (12 * (1 - NU ** 2))          # N·mm
W0 = P * R ** 4 / (64 * D)                     # 2.238 mm at Table 2's pressure
P_5MM = 64 * D * 5.0 / R ** 4                  # 26.585 MPa: 5 mm in linear theory
CASES = {"scene.toml": ("u_step", P), "scene_5mm.toml": ("u5mm_step", P_5MM)}
N_STEPS, N_RINGS = 4, 16
N_NODES, N_ELEMENTS = 1 + 3 * N_RINGS * (N_RINGS + 1), 6 * N_RINGS ** 2   # 817, 1536

# Discretisation error of the committed mesh, measured with `make_fe_bulge.py --convergence`
# (it falls as h²: the clamped 96-gon inscribed in the circle is slightly stiffer):
# centre deflection −0.081 %, max |w − w_analytic| 8.1e-4·w0 (at the centre), max slope error
# 1.0e-3·max|dw/dr|. The bounds leave a little room above those numbers.
CENTRE_REL = 1.0e-3
FIELD_REL = 1.0e-3
SLOPE_REL = 1.5e-3


def fe_mesh(prefix: str):
    """The committed mesh in the plate's own frame (mm), steps 0..4."""
    return load_mesh(FE / "bulge.inp", csv_files=[FE / f"{prefix}{k}.csv" for k in range(1, N_STEPS + 1)])


def test_linear_theory_numbers():
    assert W0 == pytest.approx(2.2381, abs=1e-4)      # not the paper's 5 mm
    assert P_5MM == pytest.approx(26.585, abs=1e-3)
    assert 6 * (P * R ** 2 / 8) / T ** 2 > 2000        # edge bending stress, MPa: far beyond yield


@pytest.mark.parametrize("prefix,pressure", CASES.values(), ids=list(CASES))
def test_fe_centre_deflection_matches_linear_theory(prefix, pressure):
    mesh = fe_mesh(prefix)
    centre = np.flatnonzero(np.linalg.norm(mesh.nodes, axis=1) == 0)
    assert mesh.node_labels[centre].tolist() == [1]
    w0 = pressure * R ** 4 / (64 * D)
    for k in range(1, N_STEPS + 1):
        u = mesh.displacements[k][centre[0]]
        assert -u[2] / (w0 * k / N_STEPS) - 1 == pytest.approx(0.0, abs=CENTRE_REL)   # bulges towards −z
        assert -u[2] / (w0 * k / N_STEPS) - 1 == pytest.approx(-8.1e-4, abs=0.1e-4)  # the measured error
        np.testing.assert_array_equal(u[:2], 0.0)
    # linear: every step is k/4 of the last (to the 1e-7 mm the CSV files are written with)
    for k in range(1, N_STEPS):
        np.testing.assert_allclose(mesh.displacements[k], mesh.displacements[N_STEPS] * k / N_STEPS, atol=2e-7)


@pytest.mark.parametrize("prefix,pressure", CASES.values(), ids=list(CASES))
def test_fe_field_matches_analytic_bulge(prefix, pressure):
    """w(r) = w0·(1 − r²/R²)² and u_r = −(t/2)·dw/dr: glsim's analytic bulge_displacements()."""
    mesh = fe_mesh(prefix)
    w0 = pressure * R ** 4 / (64 * D)
    r = np.hypot(mesh.nodes[:, 0], mesh.nodes[:, 1])
    assert np.all(mesh.nodes[:, 2] == 0) and r.max() == pytest.approx(R, abs=1e-6)
    u, = bulge_displacements(mesh.nodes, R, w0, 1, T)            # analytic, (0, 0, −1) bulge
    fe = mesh.displacements[N_STEPS]
    slope_max = 8 * w0 / (3 * np.sqrt(3) * R)                    # max |dw/dr|, at r = R/√3
    # several radii: the rings at 0, R/4, R/2, 3R/4 (node rings sit at k·R/16 exactly)
    for radius in (0.0, R / 4, R / 2, 3 * R / 4):
        ring = np.abs(r - radius) < 1e-5
        assert ring.sum() == max(1, 6 * round(radius / R * N_RINGS))
        assert np.abs(fe[ring, 2] - u[ring, 2]).max() < FIELD_REL * w0
        assert np.abs(fe[ring, :2] - u[ring, :2]).max() < SLOPE_REL * T / 2 * slope_max
    # and everywhere
    assert np.abs(fe[:, 2] - u[:, 2]).max() < FIELD_REL * w0
    assert np.linalg.norm(fe[:, :2] - u[:, :2], axis=1).max() < SLOPE_REL * T / 2 * slope_max
    # clamped edge: no motion at all
    edge = np.abs(r - R) < 1e-5
    assert edge.sum() == 6 * N_RINGS
    np.testing.assert_array_equal(fe[edge], 0.0)


@pytest.mark.parametrize("name", CASES)
def test_fe_scene_loads_like_bulge_example(name):
    scene, bulge = load_scene(FE / name), load_scene(EXAMPLES / "bulge.toml")
    # same rig, placement, speckle and render settings as examples/bulge.toml
    assert scene.cameras == bulge.cameras and scene.speckle == bulge.speckle and scene.render == bulge.render
    assert (scene.specimen.R, scene.specimen.t) == (bulge.specimen.R, bulge.specimen.t)
    assert scene.specimen.mesh.unit == "mm"

    mesh = specimen_mesh(scene)
    assert mesh.n_steps == N_STEPS + 1 and mesh.n_nodes == N_NODES and mesh.n_elements == N_ELEMENTS
    np.testing.assert_array_equal(mesh.node_labels, np.arange(1, N_NODES + 1))
    np.testing.assert_array_equal(mesh.element_labels, np.arange(1, N_ELEMENTS + 1))
    assert np.all(mesh.quads[:, 2] == mesh.quads[:, 3])          # T3 stored as collapsed Q4
    # millimetres, placed 600 mm in front of camera 0, bulging towards the cameras (−z)
    Rp, t = np.asarray(scene.specimen.R), np.asarray(scene.specimen.t)
    local = (mesh.nodes - t) @ Rp
    assert np.abs(local[:, 2]).max() < 1e-9 and np.hypot(local[:, 0], local[:, 1]).max() == pytest.approx(R)
    w0 = CASES[name][1] * R ** 4 / (64 * D)
    u_local = mesh.displacements[N_STEPS] @ Rp
    assert -u_local[0, 2] == pytest.approx(w0, rel=CENTRE_REL)
    assert mesh.displacements[N_STEPS][0, 2] < 0                 # towards camera 0


def test_fe_scene_renders_small_cpu_image():
    scene = load_scene(FE / "scene.toml")
    W, H = 64, 48                                                 # tiny, same field of view
    scale = W / scene.cameras[0].size[0]
    small = tuple(dataclasses.replace(c, size=(W, H), fx=c.fx * scale, fy=c.fy * scale,
                                      cx=(W - 1) / 2, cy=(H - 1) / 2) for c in scene.cameras)
    res = render(scene.replace(cameras=small), camera="cam1", step=N_STEPS, backend="cpu", truth=True)
    tr = res.truth
    assert res.image.shape == (H, W) and 0.2 < tr.mask.mean() < 0.9
    assert res.image[tr.mask].std() > 0.05                         # speckle, not a flat grey
    # the ground truth is the FE field: compare with linear theory at each covered pixel's material
    # point (FE error plus the linear interpolation over the 3–4.5 mm triangles: measured 4.1e-3·w0)
    Rp, t = np.asarray(scene.specimen.R), np.asarray(scene.specimen.t)
    X = (tr.X_undeformed[tr.mask] - t) @ Rp
    u, = bulge_displacements(X, R, W0, 1, T)
    du = (tr.X_deformed[tr.mask] - tr.X_undeformed[tr.mask]) @ Rp
    assert np.abs(du - u).max() < 6e-3 * W0


def test_fe_bulge_files_are_reproducible(tmp_path, monkeypatch):
    """make_fe_bulge.py rewrites the committed files: the .inp byte for byte, the CSV files to
    the last written digit (1e-7 mm; another SuperLU/BLAS build may round one digit differently)."""
    pytest.importorskip("skfem")
    spec = importlib.util.spec_from_file_location("make_fe_bulge", FE / "make_fe_bulge.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.setattr(module, "OUT", tmp_path)
    module.main()
    assert (tmp_path / "bulge.inp").read_text() == (FE / "bulge.inp").read_text()
    for prefix, _ in CASES.values():
        for k in range(1, N_STEPS + 1):
            new, old = ((p / f"{prefix}{k}.csv").read_text().splitlines() for p in (tmp_path, FE))
            assert new[0] == old[0] == "label;ux;uy;uz" and len(new) == len(old) == N_NODES + 1
            a, b = (np.array([line.split(";") for line in rows[1:]], dtype=float) for rows in (new, old))
            np.testing.assert_array_equal(a[:, 0], b[:, 0])
            np.testing.assert_allclose(a[:, 1:], b[:, 1:], rtol=0, atol=1.01e-7)
