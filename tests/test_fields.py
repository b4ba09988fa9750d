"""Random displacement fields (``[specimen.field]``, glsim/scene/fields.py): the random field's
statistics against its analytic covariance, the draws within their bounds, max_displacement_px
against a direct projection, the crack split's topology and jump, quadratic meshes, refusals by
key, reproducibility and separate streams, the library's truth keys, and a cracked plate rendered
by the CPU oracle and GL."""
import dataclasses
import math

import cv2
import numpy as np
import pytest

from glsim.errors import SceneError
from glsim.io.fe import specimen_mesh
from glsim.render import Renderer
from glsim.scene import quadratic as qd
from glsim.scene import fields as F
from glsim.scene.load import scene_from_dict
from glsim.scene.mesh import Mesh, place_mesh, plate, with_displacements

FX, Z = 2000.0, 300.0


def scene_dict(field=None, plate_=None, **specimen):
    """A 160×120 px camera (fx = fy = 2000 px, 0.15 mm/px at Z = 300 mm) before a 20 × 15 mm plate of
    8 × 6 elements (nodes every 2.5 mm), with ``field`` as its [specimen.field]."""
    sp = {"plate": plate_ or {"width": 20.0, "height": 15.0, "nx": 8, "ny": 6}, "pose": {"t": [0.0, 0.0, Z]},
          **specimen}
    if field is not None:
        sp["field"] = field
    return {"cameras": [{"name": "c", "size": [160, 120], "fx": FX, "fy": FX, "cx": 79.5, "cy": 59.5}],
            "specimen": sp}


def field_mesh(field, **kw):
    return specimen_mesh(scene_from_dict(scene_dict(field, **kw)))


# --- the random field ---------------------------------------------------------------------------

def test_random_field_covariance_matches_the_gaussian_kernel_over_seeds():
    """E[f(x)f(y)] = σ²·exp(−r²/2ℓ²) for pairs 0 … 3ℓ apart (also along Z: the field is 3-D), the mean 0,
    the components uncorrelated; each within 5 standard errors of the mean over N seeds
    (standard error: the per-seed products' sample std / √N), and the kurtosis of one value
    within 5 standard errors (√(24/N)) of the sum of M cosines' 3 − 1.5/M."""
    ell, sigma, N = 4.0, 0.3, 1500
    rf = F.RandomField(correlation_length=ell, std=(sigma, 2 * sigma, sigma), features=256)
    r = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0]) * ell
    x0 = np.array([1.3, -0.7, 0.2])
    direction = np.array([[1.0, 0.0, 0.0], [0.6, 0.0, 0.8]])
    pts = np.concatenate([[x0], x0 + r[1:, None] * direction[0], x0 + r[1:, None] * direction[1]])
    u = np.stack([F.random_displacement(rf, seed, pts) for seed in range(N)])   # (N, points, 3)
    for c, s in enumerate(rf.std):
        for d in range(2):
            for k, rk in enumerate(r):
                j = 0 if k == 0 else 1 + d * (len(r) - 1) + (k - 1)
                prod = u[:, 0, c] * u[:, j, c]
                expected = s * s * math.exp(-rk ** 2 / (2 * ell ** 2))
                assert abs(prod.mean() - expected) <= 5 * prod.std() / math.sqrt(N), (c, d, rk)
        assert abs(u[:, 0, c].mean()) <= 5 * u[:, 0, c].std() / math.sqrt(N)
    uv = u[:, 0, 0] * u[:, 0, 1]
    assert abs(uv.mean()) <= 5 * uv.std() / math.sqrt(N)
    z = u[:, 0, 0] / sigma
    kurtosis = (z ** 4).mean() / (z ** 2).mean() ** 2
    assert abs(kurtosis - (3 - 1.5 / rf.features)) <= 5 * math.sqrt(24 / N)


def test_same_scene_and_seed_give_the_same_bits_and_the_seed_changes_them():
    field = {"seed": 7, "random": {"correlation_length": 5.0, "std": [0.1, 0.1, 0.02]},
             "affine": {"gradient_max": 0.01},
             "random_bumps": {"count": [1, 3], "radius": [1.0, 3.0], "amplitude": [0.05, 0.05, 0.0]},
             "max_displacement_px": [0.1, 0.87]}
    a, b = field_mesh(field), field_mesh(field)
    assert a.displacements[1].tobytes() == b.displacements[1].tobytes()
    c = field_mesh({**field, "seed": 8})
    assert not np.array_equal(a.displacements[1], c.displacements[1])


def test_each_component_draws_from_its_own_stream():
    """Changing the affine part's bound leaves the random field's and the bumps' draws as they were:
    what is left after taking the affine part away is the same; the bumps drawn do not depend on
    the random field's settings, and bump k does not depend on the count."""
    nodes = plate(20, 15, 8, 6).nodes
    lo, hi = F.box(nodes)
    rf = F.RandomField(correlation_length=5.0, std=(0.1, 0.1, 0.0))
    rb = F.RandomBumps(count=3, radius=(1.0, 2.0), amplitude=(0.1, 0.1, 0.0))
    mesh = plate(20, 15, 8, 6)
    rest = []
    for gmax in (0.01, 0.02):
        aff = F.Affine(gradient_max=gmax)
        _, u = F.field_displacement(F.Field(seed=4, random=rf, affine=aff, random_bumps=rb), mesh)
        rest.append(u - F.affine_displacement(aff, 4, nodes, lo, hi))
    assert np.allclose(rest[0], rest[1], rtol=0, atol=1e-15)
    a = F.drawn_bumps(rb, 4, lo, hi)
    assert F.drawn_bumps(dataclasses.replace(rb, count=5), 4, lo, hi)[:3] == a
    g = F.affine_displacement(F.Affine(gradient_max=0.01), 4, nodes, lo, hi)
    assert np.array_equal(g, F.affine_displacement(F.Affine(gradient_max=0.01), 4, nodes, lo, hi))


def test_draws_stay_within_their_bounds():
    nodes = plate(20, 15, 8, 6).nodes
    lo, hi = F.box(nodes)
    rb = F.RandomBumps(count=(2, 5), radius=(1.0, 3.0), amplitude=(0.1, 0.2, 0.05))
    counts = set()
    for seed in range(200):
        bumps = F.drawn_bumps(rb, seed, lo, hi)
        counts.add(len(bumps))
        for b in bumps:
            assert lo[0] <= b.centre[0] <= hi[0] and lo[1] <= b.centre[1] <= hi[1]
            assert 1.0 <= b.radius <= 3.0
            assert all(abs(a) <= m for a, m in zip(b.amplitude, rb.amplitude))
        aff = F.Affine(gradient_max=0.02, translation_max=(0.1, 0.2, 0.0))
        u = F.affine_displacement(aff, seed, nodes, lo, hi)
        G, *_ = np.linalg.lstsq(np.column_stack([nodes[:, :2] - 0.5 * (lo + hi)[:2], np.ones(len(nodes))]), u,
                                rcond=None)
        assert np.abs(G[:2, :2]).max() <= 0.02 + 1e-12 and np.all(np.abs(G[2]) <= np.array([0.1, 0.2, 0.0]) + 1e-12)
        assert np.allclose(G[:2, 2], 0, atol=1e-12)       # w untouched by the in-plane gradient
    assert counts == {2, 3, 4, 5}
    targets = [F.drawn_scale(F.Field(seed=s, affine=F.Affine(gradient_max=0.01), max_displacement_px=(0.1, 0.87)))
               for s in range(100)]
    assert min(targets) >= 0.1 and max(targets) < 0.87 and len(set(targets)) == 100


def test_fixed_affine_and_bumps_are_the_formulas():
    m = field_mesh({"affine": {"gradient": [[0.01, -0.002], [0.003, 0.02]], "translation": [0.1, 0.0, 0.05],
                               "origin": [1.0, 2.0]},
                    "bumps": [{"centre": [2.0, -1.0], "radius": 3.0, "amplitude": [0.0, 0.2, -0.1]}]})
    X = plate(20, 15, 8, 6).nodes
    G = np.array([[0.01, -0.002, 0], [0.003, 0.02, 0], [0, 0, 0]])
    bump = np.exp(-((X[:, 0] - 2) ** 2 + (X[:, 1] + 1) ** 2) / 18)[:, None] * [0.0, 0.2, -0.1]
    expected = [0.1, 0.0, 0.05] + (X - [1.0, 2.0, 0.0]) @ G.T + bump
    assert m.n_steps == 2 and np.allclose(m.displacements[1], expected, rtol=0, atol=1e-15)


# --- load steps and scenes without a field ---------------------------------------------------------

def test_the_field_is_added_to_every_step_after_0_in_the_specimen_frame():
    field = {"random": {"correlation_length": 20.0, "std": [0.1, 0.1, 0.1]}}
    pose = {"rvec": [0.0, 0.3, 0.0], "t": [0.0, 0.0, 600.0]}
    base = {"cameras": [{"name": "c", "size": [160, 120], "fx": FX, "fy": FX, "cx": 79.5, "cy": 59.5}],
            "specimen": {"bulge": {"steps": 3}, "pose": pose}}
    plain = specimen_mesh(scene_from_dict(base))
    with_field = specimen_mesh(scene_from_dict({**base, "specimen": {**base["specimen"], "field": field}}))
    R = np.asarray(scene_from_dict(base).specimen.R)
    Xs = (plain.nodes - [0.0, 0.0, 600.0]) @ R          # back in the specimen frame
    u = F.random_displacement(F.RandomField(20.0, (0.1, 0.1, 0.1)), 0, Xs) @ R.T
    assert with_field.n_steps == plain.n_steps == 4
    assert np.array_equal(with_field.displacements[0], plain.displacements[0])
    for k in (1, 2, 3):
        assert np.allclose(with_field.displacements[k] - plain.displacements[k], u, rtol=0, atol=1e-14)


def test_a_scene_without_a_field_is_unchanged():
    d = scene_dict(plate_={"width": 20.0, "height": 15.0, "nx": 8, "ny": 6, "translations": [[0.1, 0.2, 0.0]]})
    scene = scene_from_dict(d)
    assert "field" not in scene.to_dict()["specimen"]
    m = specimen_mesh(scene)
    ref = place_mesh(with_displacements(plate(20, 15, 8, 6), [np.broadcast_to([0.1, 0.2, 0.0], (63, 3))]),
                     "mm", np.eye(3), [0.0, 0.0, Z])
    for a, b in ((m.nodes, ref.nodes), (m.quads, ref.quads), (m.node_labels, ref.node_labels)):
        assert a.tobytes() == b.tobytes()
    assert all(a.tobytes() == b.tobytes() for a, b in zip(m.displacements, ref.displacements))


def test_the_resolved_scene_renders_the_same_field():
    from glsim.scene.load import from_resolved
    import json
    field = {"seed": 2, "random": {"correlation_length": 5.0},
             "random_bumps": {"count": [0, 3], "radius": 2, "amplitude": [0.1, 0, 0]},
             "cracks": [{"start": [-10, 0], "end": [2.5, 0], "opening": [0, 0.1, 0]}], "max_displacement_px": 0.87}
    scene = scene_from_dict(scene_dict(field))
    again = scene_from_dict(*from_resolved(json.loads(scene.to_json())))
    assert again == scene
    assert specimen_mesh(again).displacements[1].tobytes() == specimen_mesh(scene).displacements[1].tobytes()


# --- max_displacement_px ------------------------------------------------------------------------

@pytest.mark.parametrize("target", [0.87, [0.1, 0.87]])
def test_max_displacement_px_against_a_direct_projection(target):
    """A fronto-parallel plate, an in-plane field: projecting X and X + u with OpenCV, the largest
    image motion of a node is the target (drawn in [0.1, 0.87) for a range)."""
    for seed in range(3):
        field = {"seed": seed, "random": {"correlation_length": 4.0, "std": [0.05, 0.08, 0.0]},
                 "affine": {"gradient_max": 0.01}, "max_displacement_px": target}
        m = field_mesh(field)
        K = np.array([[FX, 0, 79.5], [0, FX, 59.5], [0, 0, 1.0]])
        a, _ = cv2.projectPoints(m.nodes, np.zeros(3), np.zeros(3), K, None)
        b, _ = cv2.projectPoints(m.nodes + m.displacements[1], np.zeros(3), np.zeros(3), K, None)
        moved = float(np.hypot(*(b - a).reshape(-1, 2).T).max())
        expected = target if np.ndim(target) == 0 else F.drawn_scale(scene_from_dict(scene_dict(field)).specimen.field)
        assert abs(moved - expected) <= 1e-12 * expected
        assert np.ndim(target) == 0 or 0.1 <= expected < 0.87


# --- cracks -------------------------------------------------------------------------------------

def test_an_edge_crack_splits_the_mesh_along_its_edges_and_opens_one_side():
    """Crack from the left edge (−10, 0) to (2.5, 0), on the grid line y = 0: the path nodes x = −10 … 0
    are duplicated (5 copies), the tip (2.5, 0) inside the plate is not; the elements above use the
    copies, those below the originals; every other edge is still shared by two elements; the jump at
    the path nodes is opening·√((L − s)/L) (L = 12.5, s = x + 10), zero at the tip."""
    opening = np.array([0.02, 0.3, 0.0])
    m = field_mesh({"cracks": [{"start": [-10, 0], "end": [2.5, 0], "opening": opening.tolist()}]})
    base = plate(20, 15, 8, 6)
    n0 = base.n_nodes
    X = m.nodes - [0, 0, Z]
    assert m.n_nodes == n0 + 5 and m.n_elements == base.n_elements
    on_path = np.flatnonzero((np.abs(X[:n0, 1]) < 1e-12) & (X[:n0, 0] < 2.5 - 1e-9))
    assert len(on_path) == 5
    copies = np.arange(n0, n0 + 5)
    assert np.array_equal(X[copies], X[on_path]) and len(np.unique(m.node_labels)) == m.n_nodes
    centroid_y = X[m.quads].mean(axis=1)[:, 1]
    touches_path = np.isin(base.quads, on_path).any(axis=1)
    assert np.all(np.isin(m.quads[touches_path & (centroid_y > 0)], on_path, invert=True))
    assert np.all(np.isin(m.quads[touches_path & (centroid_y < 0)], copies, invert=True))
    assert np.array_equal(m.quads[~touches_path], base.quads[~touches_path])
    edges, count = np.unique(np.sort(np.stack([m.quads, np.roll(m.quads, -1, 1)], -1).reshape(-1, 2), 1), axis=0,
                             return_counts=True)
    boundary = edges[count == 1]
    path_like = (np.abs(X[boundary][:, :, 1]).max(1) < 1e-12)
    assert path_like.sum() == 2 * 5                 # the 5 path edges, now twice on the boundary
    u = m.displacements[1]
    for orig, copy in zip(on_path, copies):          # copies come in path order from the edge
        s = X[orig, 0] + 10
        assert np.allclose(u[copy] - u[orig], opening * math.sqrt((12.5 - s) / 12.5), rtol=0, atol=1e-15)
        assert np.all(u[orig] == 0)
    tip = np.flatnonzero((np.abs(X[:, 1]) < 1e-12) & (np.abs(X[:, 0] - 2.5) < 1e-12))
    assert len(tip) == 1 and np.all(u[tip] == 0)


def test_an_oblique_interior_crack_follows_the_nearest_edges_and_keeps_both_tips():
    crack = F.Crack(start=(-6.2, -4.1), end=(5.3, 3.4), opening=(0.0, 0.0, 0.2))
    base = plate(20, 15, 16, 12)
    split = F.split_along(base, crack)
    m = split.mesh
    assert split.tips == (True, True)
    new = np.arange(base.n_nodes, m.n_nodes)
    src = split.source[new]
    assert len(new) > 0 and np.array_equal(m.nodes[new], base.nodes[src])
    _, d, _, _ = F._segment(base.nodes[src, :2], np.asarray(crack.start), np.asarray(crack.end))
    assert d.max() <= 1.25 * math.sqrt(2) / 2 + 1e-12    # within half an element diagonal of the segment
    for node in (np.argmin(np.hypot(*(base.nodes[:, :2] - p).T)) for p in (crack.start, crack.end)):
        assert node not in src                              # the tips inside stay whole
    _, u = F.field_displacement(F.Field(cracks=(crack,)), base)
    jump = u[new] - u[src]
    s, d, _, L = F._segment(m.nodes[new, :2], np.asarray(crack.start), np.asarray(crack.end))
    expected = 2 * np.sqrt(s * (L - s)) / L * np.exp(-d ** 2 / (2 * L * L))
    assert np.allclose(jump[:, 2], 0.2 * expected, rtol=0, atol=1e-15) and np.all(jump[:, :2] == 0)


def test_crack_refusals_name_the_crack():
    with pytest.raises(SceneError, match=r"^specimen\.field\.cracks\[0\]\.end: .*outside the specimen"):
        field_mesh({"cracks": [{"start": [-10, 0], "end": [30, 0], "opening": [0, 0.1, 0]}]})
    with pytest.raises(SceneError, match=r"^specimen\.field\.cracks\[1\]: .*boundary"):
        field_mesh({"cracks": [{"start": [-10, 0], "end": [0, 0], "opening": [0, 0.1, 0]},
                               {"start": [-10, -7.5], "end": [0, -7.5], "opening": [0, 0.1, 0]}]})


# --- quadratic meshes -----------------------------------------------------------------------------

def q9_plate(nx=3, ny=2, w=12.0, h=8.0, centre=True):
    """A Q9 (or, ``centre=False``, Q8) plate whose mid-side nodes are moved off the straight edges
    (x += 0.3·sin y, y += 0.2·sin x on the lattice), so its elements are curved in the plane."""
    xs, ys = np.linspace(-w / 2, w / 2, 2 * nx + 1), np.linspace(-h / 2, h / 2, 2 * ny + 1)
    J, I = np.meshgrid(np.arange(2 * ny + 1), np.arange(2 * nx + 1), indexing="ij")
    x, y = xs[I], ys[J]
    odd = (I % 2 == 1) | (J % 2 == 1)
    x, y = x + odd * 0.3 * np.sin(y), y + odd * 0.2 * np.sin(x)
    nodes = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], 1)
    idx = np.arange(x.size).reshape(x.shape)
    rows = []
    for j in range(ny):
        for i in range(nx):
            a, b = 2 * i, 2 * j
            rows.append([idx[b, a], idx[b, a + 2], idx[b + 2, a + 2], idx[b + 2, a], idx[b, a + 1], idx[b + 1, a + 2],
                         idx[b + 2, a + 1], idx[b + 1, a], idx[b + 1, a + 1] if centre else qd.CENTRE_Q8])
    patches = np.array(rows)
    return Mesh(nodes, patches[:, :4], np.arange(1, len(nodes) + 1), np.arange(1, len(rows) + 1), patches=patches)


@pytest.mark.parametrize("centre", [True, False])
def test_quadratic_elements_interpolate_the_field_from_every_node(centre):
    """An affine field, evaluated at every node (mid-sides included), is reproduced exactly inside the
    curved Q9/Q8 elements: u(ξ, η) = t + G·(X(ξ, η) − o); the random field's mid-side values are its
    values there, not the corners' mean."""
    mesh = q9_plate(centre=centre)
    aff = F.Affine(gradient=((0.01, -0.004), (0.006, 0.02)), translation=(0.1, -0.05, 0.0), origin=(0.5, 0.2))
    out = F.apply_field(F.Field(affine=aff, random=F.RandomField(3.0, (0.1, 0.1, 0.0))), mesh)
    ur = F.random_displacement(F.RandomField(3.0, (0.1, 0.1, 0.0)), 0, mesh.nodes)
    u = out.displacements[1] - ur
    rng = np.random.default_rng(0)
    xi, eta = rng.uniform(-1, 1, (2, 50))
    P = qd.patch_points(mesh.patches, mesh.nodes)
    U = qd.patch_points(mesh.patches, u)
    G = np.array([[0.01, -0.004, 0], [0.006, 0.02, 0], [0, 0, 0]])
    for e in range(mesh.n_elements):
        X = qd.evaluate(P[e], xi[:, None], eta[:, None])
        assert np.allclose(qd.evaluate(U[e], xi[:, None], eta[:, None]), [0.1, -0.05, 0] + (X - [0.5, 0.2, 0]) @ G.T,
                           rtol=0, atol=1e-15)
    mids = mesh.patches[:, 4:8].ravel()
    assert np.array_equal(out.displacements[1][mids], (u + ur)[mids])
    corners = 0.5 * (ur[mesh.patches[:, [0, 1, 2, 3]]] + ur[mesh.patches[:, [1, 2, 3, 0]]]).reshape(-1, 3)
    assert np.abs(ur[mids] - corners).max() > 1e-3


def test_a_crack_splits_a_quadratic_mesh_at_its_mid_side_nodes_too():
    mesh = q9_plate(nx=4, ny=2, w=16.0, h=8.0)
    crack = F.Crack(start=(-8.0, 0.0), end=(0.0, 0.0), opening=(0.0, 0.1, 0.0))
    split = F.split_along(mesh, crack)
    m = split.mesh
    assert m.n_nodes - mesh.n_nodes == 2 + 2        # corners x = −8, −4 (0 is the tip), the 2 edges' mid-sides
    upper = np.flatnonzero(qd.patch_points(m.patches, m.nodes)[:, 8, 1] > 0)
    lower = np.flatnonzero(qd.patch_points(m.patches, m.nodes)[:, 8, 1] < 0)
    new = set(range(mesh.n_nodes, m.n_nodes))
    assert set(m.patches[upper].ravel()) & new == new and not set(m.patches[lower].ravel()) & new
    out = F.apply_field(F.Field(cracks=(crack,)), mesh)
    assert out.n_nodes == m.n_nodes and out.patches is not None


# --- refusals -----------------------------------------------------------------------------------

BAD = [
    ({}, r"specimen\.field: gives no component"),
    ({"random": {"correlation_length": -1.0}}, r"specimen\.field\.random\.correlation_length: must be > 0"),
    ({"random": {"corelation_length": 1.0}}, r"specimen\.field\.random\.corelation_length: unknown key"),
    ({"random": {}}, r"specimen\.field\.random\.correlation_length: is required"),
    ({"random": {"correlation_length": 1.0, "features": 100000}}, r"specimen\.field\.random\.features: 100000"),
    ({"random": {"correlation_length": 1.0, "std": [1, -1, 0]}}, r"specimen\.field\.random\.std: must be ≥ 0"),
    ({"random": {"correlation_length": 1.0, "std": [1, 1]}}, r"specimen\.field\.random\.std: expected a list of 3"),
    ({"seed": -1, "affine": {"gradient_max": 0.01}}, r"specimen\.field\.seed: must be an integer"),
    ({"affine": {"gradient": [[1, 0], [0, 1]], "gradient_max": 0.1}}, r"specimen\.field\.affine\.gradient_max: "),
    ({"affine": {"gradient": [[1, 0, 0], [0, 1]]}}, r"specimen\.field\.affine\.gradient: expected a 2×2 or 3×3"),
    ({"affine": {"gradient": [[1, 0], [0, "a"]]}}, r"specimen\.field\.affine\.gradient\[1\]\[1\]: expected a number"),
    ({"affine": {"translation": [1e12, 0, 0]}}, r"specimen\.field\.affine\.translation\[0\]: .*beyond"),
    ({"bumps": [{"centre": [0, 0], "radius": 0.0, "amplitude": [0, 0, 1]}]}, r"specimen\.field\.bumps\[0\]\.radius: "),
    ({"bumps": [{"centre": [0], "radius": 1.0, "amplitude": [0, 0, 1]}]}, r"specimen\.field\.bumps\[0\]\.centre: "),
    ({"random_bumps": {"count": [3, 1], "amplitude": [1, 0, 0]}}, r"specimen\.field\.random_bumps\.count: low 3"),
    ({"random_bumps": {"count": 2.5, "amplitude": [1, 0, 0]}}, r"specimen\.field\.random_bumps\.count: expected an"),
    ({"random_bumps": {"count": 2}}, r"specimen\.field\.random_bumps\.amplitude: is required"),
    ({"random_bumps": {"amplitude": [0, 0, 0]}}, r"specimen\.field\.random_bumps\.amplitude: must be ≥ 0 and not"),
    ({"cracks": [{"start": [0, 0], "end": [0, 0], "opening": [0, 1, 0]}]}, r"specimen\.field\.cracks\[0\]\.end: eq"),
    ({"cracks": [{"start": [0, 0], "end": [1, 0]}]}, r"specimen\.field\.cracks\[0\]\.opening: is required"),
    ({"affine": {"gradient_max": 0.01}, "max_displacement_px": [0, 1]}, r"specimen\.field\.max_displacement_px: "),
    ({"affine": {"gradient_max": 0.01}, "max_displacement_px": -1}, r"specimen\.field\.max_displacement_px: "),
    ({"affine": {"gradient_max": 0.01}, "max_displacement_px": True}, r"specimen\.field\.max_displacement_px: "),
    ({"affine": {"gradient_max": 0.01}, "smooth": 1}, r"specimen\.field\.smooth: unknown key"),
]


@pytest.mark.parametrize("field,message", BAD)
def test_bad_field_keys_are_refused_by_name(field, message):
    with pytest.raises(SceneError, match="^" + message) as info:
        scene_from_dict(scene_dict(field))
    assert " — " in str(info.value)          # and a fix


def test_scaling_refusals_at_the_mesh():
    with pytest.raises(SceneError, match=r"^specimen\.field\.max_displacement_px: the field has no in-plane"):
        field_mesh({"random": {"correlation_length": 2.0, "std": [0, 0, 0.1]}, "max_displacement_px": 0.5})
    with pytest.raises(SceneError, match=r"^specimen\.field\.max_displacement_px: .*behind camera c"):
        field_mesh({"affine": {"gradient_max": 0.01}, "max_displacement_px": 0.5}, pose={"t": [0.0, 0.0, -300.0]})


# --- the library ----------------------------------------------------------------------------------

def test_library_truth_keys_follow_the_field_seed_not_the_speckle_seed():
    from glsim.workflows.library import expand
    spec = {"mode": "grid", "seed": 1, "steps": [0, 1], "scene": scene_dict(
        {"seed": 0, "random": {"correlation_length": 5.0, "std": [0.05, 0.05, 0.0]}, "max_displacement_px": 0.5}),
        "vary": {"specimen": {"field": {"seed": {"range": [0, 2]}}}, "speckle": {"seed": [0, 5]}}}
    plan = expand(spec, ".")
    key = {(v.params["specimen.field.seed"], v.params["speckle.seed"]): v.id for v in plan.variants}
    truth = {(j.variant, j.step): j.truth for j in plan.jobs}
    for step in (0, 1):
        assert truth[key[0, 0], step] == truth[key[0, 5], step]
        assert truth[key[1, 0], step] == truth[key[1, 5], step]
        assert truth[key[0, 0], step] != truth[key[1, 0], step]


# --- rendering ------------------------------------------------------------------------------------

@pytest.mark.parametrize("backend", ["cpu", pytest.param("gl", marks=pytest.mark.gl)])
def test_a_cracked_plate_renders_both_sides_with_a_hole_only_in_the_opening(backend, ctx_for):
    """An edge crack from (−10, 0) to (2.5, 0) opened by 0.6 mm in v: at step 0 (the split mesh undeformed)
    every pixel inside the plate sees it; at step 1 the only pixels inside that see no element are
    in the gap between the crack's two edges, 0 < y < the opening interpolated linearly between the
    path nodes (each edge is straight), and the gap's inside is open; elements on both sides are seen."""
    scene = scene_from_dict({**scene_dict({"cracks": [{"start": [-10, 0], "end": [2.5, 0], "opening": [0, 0.6, 0]}]}),
                             "render": {"mode": "exact", "backend": backend}})
    tol = 1e-6 if backend == "cpu" else 1e-4     # mm at the plate: the oracle in float64; GL float32 at worst
    u, v = np.meshgrid(np.arange(160.0), np.arange(120.0))
    x, y = (u - 79.5) * Z / FX, (v - 59.5) * Z / FX        # each pixel centre's ray on the plate's plane
    inside = (np.abs(x) <= 9.0) & (np.abs(y) <= 6.0)
    xs = np.arange(-10.0, 2.51, 2.5)
    gap = np.interp(x, xs, 0.6 * np.sqrt((2.5 - xs) / 12.5), right=0.0)
    with Renderer(scene, backend, ctx=ctx_for(backend)) as r:
        t0 = r.render(0, 0, truth=True).truth
        t1 = r.render(0, 1, truth=True).truth
        cy = r.mesh.nodes[r.mesh.quads].mean(axis=1)[:, 1]
    assert t0.mask[inside].all()
    hole = inside & ~t1.mask
    assert hole.any()
    assert np.all((y[hole] > -tol) & (y[hole] < gap[hole] + tol))
    assert not t1.mask[inside & (y > tol) & (y < gap - tol)].any()
    seen = t1.element[inside & t1.mask]
    assert (cy[seen] > 0).any() and (cy[seen] < 0).any()


@pytest.mark.parametrize("mode", ["exact", "fast"])
@pytest.mark.parametrize("backend", ["cpu", pytest.param("gl", marks=pytest.mark.gl)])
def test_the_split_mesh_undeformed_renders_the_bytes_of_the_unsplit_one(backend, mode, ctx_for):
    """Step 0 of a cracked plate (duplicated nodes, the same positions) against the plain plate: the same
    image bytes and element map — no seam along the split edges."""
    out = []
    for sp in ({"field": {"cracks": [{"start": [-10, 0], "end": [2.5, 0], "opening": [0, 0.6, 0]}]}}, {}):
        d = scene_dict(**({"plate_": {"width": 20.0, "height": 15.0, "nx": 8, "ny": 6,
                                      "translations": [[0.1, 0.0, 0.0]]}} if not sp else {}))
        d["specimen"].update(sp)
        with Renderer(scene_from_dict({**d, "render": {"mode": mode, "backend": backend}}), backend,
                      ctx=ctx_for(backend)) as r:
            res = r.render(0, 0, truth=True)
        out.append((res.image.tobytes(), res.truth.element))
    assert out[0][0] == out[1][0] and np.array_equal(out[0][1], out[1][1])


def test_the_example_in_docs_scene_md_loads_and_stays_within_its_bound():
    import re
    import tomllib
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / "scene.md").read_text()
    section = text[text.index("## Random displacement fields"):]
    d = tomllib.loads(re.search(r"```toml\n(.*?)```", section, re.S)[1])
    d["cameras"] = [{"name": "c", "size": [256, 256], "fx": 3000.0, "fy": 3000.0, "cx": 127.5, "cy": 127.5}]
    m = specimen_mesh(scene_from_dict(d))
    assert m.n_nodes == 65 * 65 + 32          # the edge crack's 33 path nodes but its tip
    largest = float(np.hypot(*m.displacements[1][:, :2].T).max()) * 3000.0 / 300.0
    assert 0.05 <= largest < 0.87 and abs(largest - F.drawn_scale(scene_from_dict(d).specimen.field)) < 1e-12


def test_a_crack_splits_a_triangle_mesh():
    """Linear triangles (collapsed quads a, b, c, c): an edge crack along y = 0 to the tip (2.5, 0) splits
    the 5 path nodes but the tip, the triangles above take the copies, and the jump is the profile's."""
    q = plate(20, 15, 8, 6)
    tris = np.concatenate([q.quads[:, [0, 1, 2, 2]], q.quads[:, [0, 2, 3, 3]]])
    mesh = Mesh(q.nodes, tris, q.node_labels, np.arange(1, len(tris) + 1))
    crack = F.Crack(start=(-10.0, 0.0), end=(2.5, 0.0), opening=(0.0, 0.1, 0.0))
    split = F.split_along(mesh, crack)
    m, n0 = split.mesh, mesh.n_nodes
    assert m.n_nodes == n0 + 5 and split.tips == (False, True)
    src = split.source[n0:]
    assert np.allclose(m.nodes[src, 1], 0) and np.all(m.nodes[src, 0] < 2.5)
    cy = m.nodes[m.quads].mean(axis=1)[:, 1]
    assert not np.isin(m.quads[cy < 0], np.arange(n0, m.n_nodes)).any()
    assert not np.isin(m.quads[cy > 0], src).any()
    _, u = F.field_displacement(F.Field(cracks=(crack,)), mesh)
    s = m.nodes[src, 0] + 10
    assert np.allclose(u[n0:] - u[src], np.outer(np.sqrt((12.5 - s) / 12.5), [0, 0.1, 0]), rtol=0, atol=1e-15)
