"""Normals and the paper's Phong lighting (§2.2.1, eqs. 10–13): glsim/effects/lighting.py against
analytic results, and shaders/shade.glsl against glsim/effects/lighting.py."""
import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import minimize_scalar

from glsim.effects import lighting as shade
from glsim.errors import SceneError
from glsim.backends.gl.programs import ProgramCache
from glsim.effects.lighting import LightArrays
from glsim.check import closed_forms

GLSL_DIR = Path(__file__).parent / "glsl"


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _lights(*lights, R=None, t=None) -> LightArrays:
    return shade.lights_to_camera(list(lights), R, t)


def _rot(axis, angle):
    """Rotation matrix about ``axis`` by ``angle`` (rad), Rodrigues."""
    k = _unit(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _perp(d):
    p = np.cross(d, [1.0, 0, 0] if abs(d[0]) < 0.9 else [0, 1.0, 0])
    return _unit(p)


def _reference_phong(X, N, lights: LightArrays, ambient, k_r, k_s, r):
    """The paper's eq. 13 written out point by point and light by light (pow of R·V)."""
    out = np.empty(len(X))
    for p, (x, n) in enumerate(zip(X, N)):
        nn = np.linalg.norm(n)
        n = n / nn if nn > 0 else n
        v = -x / np.linalg.norm(x)
        if n @ v < 0:
            n = -n
        total = ambient
        for i in range(len(lights)):
            l = lights.pos[i] - x
            d = np.linalg.norm(l)
            l = l / d
            nl = n @ l
            rv = (2 * nl * n - l) @ v
            spec = rv ** r if nl > 0 and rv > 0 else 0.0
            spot = 1.0
            if np.any(lights.dir[i] != 0):
                spot = shade.spot_factor(-l @ lights.dir[i], lights.cos_cutoff[i], lights.cos_inner[i])
            att = lights.intensity[i] / (1 + lights.attenuation[i] * d * d)
            total += spot * att * (k_r * max(nl, 0.0) + k_s * spec)
        out[p] = total
    return out


def _random_scene(rng, n, near_highlight=0.5):
    """Points in front of the camera, random unit normals (a share of them near the mirror
    direction of light 0, where the specular term is large), some zero normals, three lights:
    a point light, a smooth-edged spot and a hard-edged spot."""
    lights = _lights(
        dict(position=(150, -80, 0), intensity=0.4, attenuation=1e-6),
        dict(position=(-200, 50, 50), direction=(0.3, 0, 1), intensity=0.3, attenuation=2e-6,
             cutoff_deg=25, edge_deg=8),
        dict(position=(0, 200, -20), direction=(0, -0.4, 1), intensity=0.5, cutoff_deg=8, edge_deg=0))
    X = np.column_stack([rng.uniform(-80, 80, (n, 2)), rng.uniform(400, 600, n)])
    N = _unit(rng.normal(size=(n, 3)))
    H = _unit(_unit(-X) + _unit(lights.pos[0] - X))              # half vector: R = V for N = H
    m = int(n * near_highlight)
    N[:m] = _unit(H[:m] + rng.normal(scale=0.03, size=(m, 3)))
    N[::97] = 0.0
    return X, N, lights


# ---------------------------------------------------------------------------------------------
# normals


def _sphere(n, R=50.0):
    """Latitude-longitude sphere: n rings of quads between the poles, 2n around, collapsed
    triangles (pole, a, b, b) at the caps; corner order gives outward normals."""
    nlat, nlon = n, 2 * n
    P, L = np.meshgrid(np.arange(1, nlat) * np.pi / nlat, np.arange(nlon) * 2 * np.pi / nlon, indexing="ij")
    ring = np.stack([np.sin(P) * np.cos(L), np.sin(P) * np.sin(L), np.cos(P)], -1).reshape(-1, 3)
    nodes = R * np.vstack([[0, 0, 1], ring, [0, 0, -1]])
    south = len(nodes) - 1

    def idx(i, j):
        return 1 + i * nlon + j % nlon

    quads = []
    for j in range(nlon):
        quads.append((0, idx(0, j), idx(0, j + 1), idx(0, j + 1)))
        quads.append((south, idx(nlat - 2, j + 1), idx(nlat - 2, j), idx(nlat - 2, j)))
        quads += [(idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1)) for i in range(nlat - 2)]
    return nodes, np.array(quads)


def test_vertex_normals_on_a_sphere_converge_to_the_radial_direction():
    """Max angle (rad) between vertex normal and radius: first order over the whole sphere
    (the rings next to the poles, where the cap triangles meet much larger quads), second
    order away from the poles; the poles themselves are exact by symmetry."""
    whole, band = [], []
    for n in (8, 16, 32, 64):
        nodes, quads = _sphere(n)
        en = shade.element_normals(nodes, quads)
        centroids = nodes[quads].mean(axis=1)
        assert (np.einsum("ij,ij->i", en, _unit(centroids)) > 0.99).all()   # outward
        vn = shade.vertex_normals(nodes, quads)
        ang = np.arccos(np.clip(np.einsum("ij,ij->i", vn, _unit(nodes)), -1, 1))
        whole.append(ang.max())
        band.append(ang[np.abs(nodes[:, 2]) <= 0.9 * 50].max())
        np.testing.assert_allclose(vn[[0, -1]], [[0, 0, 1], [0, 0, -1]], atol=1e-15)
    whole, band = np.array(whole), np.array(band)
    assert (whole[:-1] / whole[1:] > 1.9).all(), whole          # measured 1.95, 1.99, 2.0
    assert (band[1:-1] / band[2:] > 3.0).all(), band            # measured (2.7,) 3.2, 4.0
    assert whole[-1] < 0.013 and band[-1] < 1.2e-3


def test_flat_plate_vertex_normals_equal_element_normals():
    rng = np.random.default_rng(0)
    g = np.stack(np.meshgrid(np.arange(6.0), np.arange(5.0), indexing="xy"), -1).reshape(-1, 2)
    g += rng.uniform(-0.2, 0.2, g.shape)                         # irregular, still convex quads
    nodes = np.column_stack([g * 3.7, np.full(len(g), 250.0)])
    quads = np.array([(r * 6 + c, r * 6 + c + 1, (r + 1) * 6 + c + 1, (r + 1) * 6 + c)
                      for r in range(4) for c in range(5)])
    en = shade.element_normals(nodes, quads)
    vn = shade.vertex_normals(nodes, quads)
    assert np.array_equal(en, np.tile([0.0, 0.0, 1.0], (len(quads), 1)))
    assert np.array_equal(vn, np.tile([0.0, 0.0, 1.0], (len(nodes), 1)))
    # the same plate tilted and moved: equal to rounding
    Rm = _rot([0.3, -1.0, 0.2], 0.7)
    tilted = nodes @ Rm.T + [10.0, -40.0, 300.0]
    en = shade.element_normals(tilted, quads)
    vn = shade.vertex_normals(tilted, quads)
    np.testing.assert_allclose(en, np.tile(Rm[:, 2], (len(quads), 1)), atol=2e-16 * 4)
    np.testing.assert_allclose(vn, np.tile(Rm[:, 2], (len(nodes), 1)), atol=2e-16 * 4)


def test_collapsed_triangle_and_degenerate_normals_are_finite():
    nodes = np.array([[0, 0, 0], [2, 0, 0], [0, 3, 0], [1, 1, 0], [5, 5, 5], [6, 6, 6], [7, 7, 7],
                      [0, 0, 1], [9, 9, 9]], dtype=float)
    quads = np.array([
        [0, 1, 2, 2],        # collapsed triangle, +z
        [4, 4, 4, 4],        # all corners one point
        [4, 5, 6, 5],        # collinear corners
        [0, 1, 3, 3],        # another triangle
    ])
    en = shade.element_normals(nodes, quads)
    assert np.isfinite(en).all()
    np.testing.assert_array_equal(en[0], [0, 0, 1])
    np.testing.assert_array_equal(en[1:3], 0.0)
    np.testing.assert_array_equal(en[3], [0, 0, 1])
    vn = shade.vertex_normals(nodes, quads)
    assert np.isfinite(vn).all()
    np.testing.assert_array_equal(vn[[0, 1, 2, 3]], np.tile([0, 0, 1.0], (4, 1)))
    np.testing.assert_array_equal(vn[[4, 5, 6, 7, 8]], 0.0)   # degenerate-only or unused nodes
    # a triangle's repeated corner counts once: node 2 is shared by a triangle (+z, area 1/2)
    # and a quad in the x = 0 plane (−x, area 1); the normal is their area-weighted mean
    nodes = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 0], [0, 0, 1], [0, 1, 1]], dtype=float)
    quads = np.array([[0, 1, 2, 2], [2, 3, 4, 1]])
    en = shade.element_normals(nodes, quads)
    np.testing.assert_allclose(en, [[0, 0, 1], [-1, 0, 0]], atol=1e-16)
    vn = shade.vertex_normals(nodes, quads)
    np.testing.assert_allclose(vn[2], _unit([-1.0, 0, 0.5]), atol=1e-15)


def _central(f, x: np.ndarray, h: float) -> np.ndarray:
    """Central differences of f (values (..., m)) at x (n, 3) per component: (3, ..., m)."""
    out = []
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        out.append((f(x + e) - f(x - e)) / (2 * h))
    return np.array(out)


def test_normal_jacobian_matches_central_differences():
    """∂(normals)/∂(nodes) (image Jacobians with lighting) against central differences of
    element_normals and vertex_normals, node by node, on a warped grid with a collapsed triangle
    and a zero-area element (whose normal, and its derivative, is 0). δ = 1e-6 mm on unit-size
    elements: truncation O(δ²), rounding ~1e-16/δ; 1e-8 allowed."""
    x, y = np.meshgrid(np.arange(5.0), np.arange(4.0))
    rng = np.random.default_rng(2)
    nodes = np.column_stack([x.ravel(), y.ravel(), 0.3 * np.sin(x.ravel()) + 0.1 * rng.normal(size=20)])
    a = (np.arange(3)[:, None] * 5 + np.arange(4)).ravel()
    quads = np.column_stack([a, a + 1, a + 6, a + 5])
    quads[4] = [4, 9, 9, 4]        # zero area: two corners twice
    quads[7] = [7, 8, 13, 13]      # a collapsed triangle
    for flat, normals in ((True, shade.element_normals), (False, shade.vertex_normals)):
        D = shade.normal_jacobian(nodes, quads, flat).toarray()
        for j in range(len(nodes)):
            fd = _central(lambda p: normals(np.where(np.arange(len(nodes))[:, None] == j, p, nodes), quads).ravel(),
                          nodes[j], 1e-6)
            np.testing.assert_allclose(D[:, 3 * j:3 * j + 3], fd.T, rtol=0, atol=1e-8)
        assert not D[3 * 4:3 * 5].any() if flat else True


def test_phong_gradient_matches_central_differences():
    """phong_gradient's I is phong's, and its ∂I/∂X, ∂I/∂N and ∂I/∂X through the view direction
    (X and the lights moved together) match central differences at 2000
    random points 550–650 mm away with random normals (some facing away: flipped), lit by a
    point light with attenuation, a highlight (shininess 7) and a spotlight with a smooth edge
    over the points (each term non-zero somewhere, checked). Allowed: the differences' rounding,
    ~10 ulps of I ≤ 1 over 2δ (δ = 1e-4 mm for X: 1e-11, 1e-10 allowed; δ = 1e-6 for N: 1e-9),
    above their truncation (I's third derivatives · δ²/6: ≤ 1e-14 over ≥ 100 mm to the lights,
    ≤ r³ · 1e-12/6 ≈ 6e-11 for N)."""
    rng = np.random.default_rng(0)
    lights = _lights({"position": [100, 50, 0], "intensity": 0.3, "attenuation": 1e-5},
                     {"position": [-80, 20, -50], "direction": [0.2, 0, 1], "cutoff_deg": 30, "edge_deg": 10,
                      "intensity": 0.5})
    n = 2000
    X = np.column_stack([rng.uniform(-200, 200, n), rng.uniform(-30, 30, n), rng.uniform(550, 650, n)])
    N = rng.normal(size=(n, 3)) + [0, 0, -1]
    args = (lights, -0.04, 0.8, 0.5, 7.0)
    I, dX, dN, dV = shade.phong_gradient(X, N, *args)
    np.testing.assert_array_equal(I, shade.phong(X, N, *args))
    def view_only(p):   # X and the lights moved by the same δ = p − X: only the view direction changes
        return shade.phong(p, N, dataclasses.replace(lights, pos=lights.pos + (p - X)[0]), *args[1:])

    for got, fd, tol in ((dX, _central(lambda p: shade.phong(p, N, *args), X, 1e-4), 1e-10),
                         (dV, _central(view_only, X, 1e-4), 1e-10),
                         (dN, _central(lambda p: shade.phong(X, p, *args), N, 1e-6), 1e-9)):
        np.testing.assert_allclose(got, fd.T, rtol=0, atol=tol)
        assert np.abs(got).max() > 1e4 * tol
    cos = np.einsum("nd,d->n", -_unit(lights.pos[1] - X), lights.dir[1])
    assert ((cos > lights.cos_cutoff[1]) & (cos < lights.cos_inner[1])).sum() > 100   # on the smooth edge
    assert (np.einsum("nd,nd->n", N, -X) < 0).sum() > 100                           # flipped normals


# ---------------------------------------------------------------------------------------------
# lighting, analytic


def test_phong_equals_the_paper_formula_written_out():
    """The vectorised phong (specular as exp(r·log1p(−|R−V|²/2))) against eq. 13 written out
    with pow(R·V, r), light by light."""
    rng = np.random.default_rng(5)
    X, N, lights = _random_scene(rng, 400)
    N = N * rng.uniform(0.5, 2.0, (len(N), 1))                   # normals need not be unit
    for r in (0.0, 1.0, 20.0, 400.0):
        I = shade.phong(X, N, lights, -10 / 255, 0.7, 0.5, r)
        ref = _reference_phong(X, N, lights, -10 / 255, 0.7, 0.5, r)
        np.testing.assert_allclose(I, ref, rtol=0, atol=1e-13)      # pow(R·V, 400) itself loses 400·2⁻⁵³
    # broadcasting: one normal for many points, (H, W, 3) images
    I = shade.phong(X.reshape(20, 20, 3), [0.0, 0.0, -1.0], lights, 0.0, 1.0, 0.0, 1.0)
    assert I.shape == (20, 20)


@pytest.mark.parametrize("theta_deg", [0.0, 10.0, 30.0, 60.0, 85.0, 89.9, 95.0, 150.0])
def test_lambert_on_a_tilted_plane_is_the_cosine(theta_deg):
    """Point light 1e15 mm away along a direction at θ from the plane normal, k_s = 0:
    I = I_a + I_i·k_r·max(cos θ, 0) to 1e-12 over the plate (eq. 10)."""
    n = np.array([np.sin(0.5), 0.0, -np.cos(0.5)])              # plane tilted 28.6°, facing the camera
    u = _rot(np.cross(n, [0.0, 1.0, 0.0]), np.radians(theta_deg)) @ n
    rng = np.random.default_rng(1)
    a, b = _perp(n), np.cross(n, _perp(n))
    X = [0.0, 0.0, 500.0] + rng.uniform(-60, 60, (200, 1)) * a + rng.uniform(-60, 60, (200, 1)) * b
    lights = _lights(dict(position=X.mean(0) + 1e15 * u, intensity=0.6))
    I = shade.phong(X, n, lights, ambient=-0.04, k_r=0.8, k_s=0.0, shininess=400)
    expected = -0.04 + 0.6 * 0.8 * max(np.cos(np.radians(theta_deg)), 0.0)
    np.testing.assert_allclose(I, expected, rtol=0, atol=1e-12)


def test_specular_peak_lies_at_the_mirror_point():
    """Along a line on a tilted plane the specular term peaks where the camera sees the light
    mirrored: the intersection of the plane with the segment from the light to the camera's
    mirror image (to 1e-6 mm)."""
    n = _unit([0.25, -0.15, -1.0])
    P0 = np.array([12.0, -8.0, 480.0])
    light = np.array([180.0, 90.0, 30.0])
    mirror_cam = 2 * (P0 @ n) * n                                # camera (origin) mirrored in the plane
    t = ((P0 - light) @ n) / ((mirror_cam - light) @ n)
    M = light + t * (mirror_cam - light)
    assert abs((M - P0) @ n) < 1e-9
    u = _unit(M - P0)                                            # a line on the plane through P0 and M
    lights = _lights(dict(position=light, intensity=1.0))

    def spec(s):
        return shade.phong(P0 + np.multiply.outer(s, u), n, lights, 0.0, 0.0, 1.0, 400.0)

    s = np.linspace(-200, 200, 40001)                            # coarse scan, 0.01 mm
    k = int(np.argmax(spec(s)))
    best = minimize_scalar(lambda x: -spec(x), bounds=(s[k - 1], s[k + 1]), method="bounded",
                           options={"xatol": 1e-10})
    assert spec(best.x) == pytest.approx(1.0, abs=1e-12)
    assert abs(best.x - np.linalg.norm(M - P0)) < 1e-6
    # the total with diffuse and attenuation peaks elsewhere, the specular term does not
    assert spec(best.x + 0.05) < spec(best.x) and spec(best.x - 0.05) < spec(best.x)


def _spot_scan(theta_deg, cutoff, edge):
    """Relative brightness of points at angles θ off a spotlight's axis, each point facing the
    light (N·L = 1), k_r = 1, no attenuation: I = spot factor."""
    pos = np.array([10.0, -5.0, 0.0])
    axis = _unit([0.1, 0.05, 1.0])
    perp = _perp(axis)
    th = np.radians(np.asarray(theta_deg))
    X = pos + 400.0 * (np.cos(th)[:, None] * axis + np.sin(th)[:, None] * perp)
    lights = _lights(dict(position=pos, direction=axis * 3, intensity=1.0, cutoff_deg=cutoff, edge_deg=edge))
    return shade.phong(X, pos - X, lights, 0.0, 1.0, 0.0, 1.0)


def test_spotlight_hard_edge_switches_exactly_at_the_cutoff():
    cutoff = 23.0
    I = _spot_scan([0.0, 10.0, cutoff - 1e-9, cutoff + 1e-9, 40.0], cutoff, 0.0)
    np.testing.assert_allclose(I, [1, 1, 1, 0, 0], rtol=0, atol=1e-13)
    c = np.cos(np.radians(cutoff))
    assert shade.spot_factor(c, c, c) == 1.0                     # on at exactly the cutoff
    assert shade.spot_factor(np.nextafter(c, -1), c, c) == 0.0


def test_spotlight_smooth_edge():
    """smoothstep(cos cutoff, cos(cutoff − edge), cos θ): 1 inside cutoff − edge, 0 outside the
    cutoff, monotone between, 0.5 where cos θ is midway between the two cosines."""
    cutoff, edge = 30.0, 10.0
    theta = np.linspace(0, 45, 9001)
    I = _spot_scan(theta, cutoff, edge)
    assert np.all(np.diff(I) <= 1e-15)
    np.testing.assert_allclose(I[theta <= cutoff - edge - 1e-9], 1.0, atol=1e-13)
    np.testing.assert_allclose(I[theta >= cutoff + 1e-9], 0.0, atol=1e-13)
    assert ((I > 0) & (I < 1))[(theta > cutoff - edge + 1e-6) & (theta < cutoff - 1e-6)].all()
    mid = np.degrees(np.arccos(0.5 * (np.cos(np.radians(cutoff)) + np.cos(np.radians(cutoff - edge)))))
    assert _spot_scan([mid], cutoff, edge)[0] == pytest.approx(0.5, abs=1e-12)
    assert cutoff - edge < mid < cutoff


def test_attenuation_with_distance():
    """I(d)·(1 + k d²) is constant (eq. 13), over 1 mm … 10 m."""
    k = 2.5e-4
    n = _unit([0.2, 0.1, -1.0])
    X0 = np.array([5.0, 3.0, 500.0])
    d = np.geomspace(1.0, 1e4, 50)
    pos = X0 + d[:, None] * n
    I = np.array([shade.phong(X0, n, _lights(dict(position=p, intensity=0.7, attenuation=k)), 0.0, 0.9, 0.0, 1.0)
                  for p in pos])
    np.testing.assert_allclose(I * (1 + k * d ** 2), 0.7 * 0.9, rtol=1e-12)


def test_back_facing_normals_are_flipped_and_zero_normals_give_ambient():
    rng = np.random.default_rng(2)
    X, N, lights = _random_scene(rng, 500, near_highlight=0.0)
    N[::97] = _unit(rng.normal(size=N[::97].shape))
    a = shade.phong(X, N, lights, 0.01, 0.7, 0.5, 50.0)
    b = shade.phong(X, -N, lights, 0.01, 0.7, 0.5, 50.0)
    np.testing.assert_array_equal(a, b)
    # a plate lit only from behind (light on the far side from the camera): ambient only
    n = np.array([0.0, 0.0, -1.0])
    X = np.column_stack([rng.uniform(-20, 20, (50, 2)), np.full(50, 500.0)])
    behind = _lights(dict(position=(0, 0, 900), intensity=1.0))
    for normal in (n, -n):
        np.testing.assert_array_equal(shade.phong(X, normal, behind, 0.02, 1.0, 1.0, 10.0), 0.02)
    # degenerate normal, a point at the light, a point at the camera: finite, ambient only
    front = _lights(dict(position=(0, 0, 0), intensity=1.0), dict(position=(0, 0, 500), intensity=1.0))
    I = shade.phong([[0, 0, 500.0], [1, 2, 500.0], [0, 0, 0.0]], [[0, 0, -1.0], [0, 0, 0], [0, 0, 0]],
                    front, 0.02, 1.0, 1.0, 10.0)
    assert np.isfinite(I).all()
    np.testing.assert_allclose(I[1:], 0.02)


def test_lights_to_camera_transforms_and_validates():
    Rm = _rot([1.0, 2.0, 0.5], 0.4)
    t = np.array([5.0, -3.0, 100.0])
    L = shade.lights_to_camera(
        [dict(position=(1, 2, 3), intensity=0.3),
         type("Spot", (), dict(position=(0, 0, -50), direction=(0, 0, 2), intensity=0.5, attenuation=1e-5,
                                cutoff_deg=20.0, edge_deg=5.0))()], Rm, t)
    np.testing.assert_allclose(L.pos, [Rm @ [1, 2, 3] + t, Rm @ [0, 0, -50] + t], atol=1e-13)
    np.testing.assert_allclose(L.dir, [[0, 0, 0], Rm[:, 2]], atol=1e-15)
    np.testing.assert_allclose(L.cos_cutoff, [-1, np.cos(np.radians(20))])
    np.testing.assert_allclose(L.cos_inner, [-1, np.cos(np.radians(15))])
    np.testing.assert_array_equal(L.intensity, [0.3, 0.5])
    np.testing.assert_array_equal(L.attenuation, [0.0, 1e-5])
    assert len(L) == 2 and all(a.dtype == np.float64 for a in vars(L).values())
    spot = dict(position=(0, 0, 0), direction=(0, 0, 1), intensity=1.0, cutoff_deg=20.0)
    for bad, key in ((dict(spot, cutoff_deg=0.0), r"lights\[0\]\.cutoff_deg"),
                     (dict(spot, cutoff_deg=190.0), r"lights\[0\]\.cutoff_deg"),
                     (dict(spot, edge_deg=25.0), r"lights\[0\]\.edge_deg"),
                     (dict(spot, direction=(0, 0, 0)), r"lights\[0\]\.direction"),
                     (dict(spot, attenuation=-1.0), r"lights\[0\]\.attenuation"),
                     (dict(spot, position=(0, 0)), r"lights\[0\]\.position")):
        with pytest.raises(SceneError, match=key):
            shade.lights_to_camera([bad])
    assert len(shade.lights_to_camera([])) == 0


def test_combine_and_saturated_fraction():
    grey = np.array([0.0, 0.2, 0.5, 0.9])
    I = np.array([0.1, -0.3, 1.2, 0.2])
    np.testing.assert_array_equal(shade.combine(grey, I, "additive"), grey + I)       # not clipped
    np.testing.assert_array_equal(shade.combine(grey, I, "multiplicative"), grey * I)
    with pytest.raises(ValueError, match="additive"):
        shade.combine(grey, I, "screen")
    assert shade.saturated_fraction(shade.combine(grey, I, "additive")) == 0.75       # -0.1, 1.7, 1.1
    assert shade.saturated_fraction(np.array([[0.0, 1.0], [0.5, 0.999]])) == 0.5
    assert shade.saturated_fraction(np.zeros((0,))) == 0.0


# ---------------------------------------------------------------------------------------------
# GLSL twin


UNIFORMS = ("u_light_pos", "u_light_dir", "u_light_intensity", "u_light_att", "u_light_cos_cutoff",
            "u_light_cos_inner", "u_ambient", "u_kr", "u_ks", "u_shininess")


def _run_shade_check(ctx, X, N, grey, lights: LightArrays, ambient, k_r, k_s, r, model):
    cache = ProgramCache(ctx, dirs=(GLSL_DIR,))
    defines = {"MAX_LIGHTS": len(lights)}
    if model == "multiplicative":
        defines["LIGHT_MULTIPLICATIVE"] = None
    prog = cache.compute("shade_check.comp", defines)
    n = len(X)
    bufs = [ctx.buffer(np.ascontiguousarray(a, "f4").tobytes()) for a in (X, N, grey)]
    bufs.append(ctx.buffer(reserve=n * 2 * 4))
    for i, b in enumerate(bufs):
        b.bind_to_storage_buffer(i)
    values = (lights.pos, lights.dir, lights.intensity, lights.attenuation, lights.cos_cutoff,
              lights.cos_inner, ambient, k_r, k_s, r)
    for name, value in zip(UNIFORMS, values):
        prog[name].write(np.asarray(value, "f4").tobytes())
    prog["u_count"].value = n
    prog.run(group_x=(n + 63) // 64)
    out = np.frombuffer(bufs[3].read(), "f4").reshape(n, 2).astype(float)
    for b in bufs:
        b.release()
    cache.release()
    return out[:, 0], out[:, 1]


def _near_a_switch(X, N, lights, eps=1e-5):
    """Points where float32 (errors ~1e-7 in these cosines) may land on the other side of a
    discontinuity: N·V ≈ 0 (flip), N·L ≈ 0 (the specular switch [N·L > 0]), cos θ ≈ cos cutoff
    of a hard-edged spot."""
    Nu = np.where(np.linalg.norm(N, axis=1, keepdims=True) > 0, N, [[0, 0, 1.0]])
    Nu = _unit(Nu)
    V = _unit(-X)
    near = np.abs(np.einsum("ij,ij->i", Nu, V)) < eps
    for i in range(len(lights)):
        L = _unit(lights.pos[i] - X)
        near |= np.abs(np.einsum("ij,ij->i", Nu, L)) < eps
        if np.any(lights.dir[i] != 0) and lights.cos_inner[i] <= lights.cos_cutoff[i]:
            near |= np.abs(-L @ lights.dir[i] - lights.cos_cutoff[i]) < eps
    return near


@pytest.mark.gl
@pytest.mark.parametrize("model", ["additive", "multiplicative"])
@pytest.mark.parametrize("shininess", [1.0, 20.0, 400.0])
def test_glsl_phong_and_combine_match_numpy(gl_ctx, shininess, model):
    """shade.glsl (float32) against shade.py (float64) on the float32-rounded inputs, 20 000
    points (half near light 0's highlight, a quarter back-facing), 3 lights (point, smooth spot
    with 13 % of the points on its edge, hard spot with 28 % outside it): per point within what
    GLSL 4.50's precision rules allow (glsim.check.closed_forms.phong, of I and after combine).
    Points within 1e-5 of a switch (flip, N·L = 0, hard spot edge) are left out (about 20 of
    20 000)."""
    rng = np.random.default_rng(11)
    X, N, lights = _random_scene(rng, 20000)
    grey = rng.uniform(0, 1, len(X))
    X32, N32, g32 = (a.astype(np.float32).astype(float) for a in (X, N, grey))
    lights32 = LightArrays(*(getattr(lights, f).astype(np.float32).astype(float) for f in
                             ("pos", "dir", "intensity", "attenuation", "cos_cutoff", "cos_inner")))
    args = (-10 / 255, 0.7, 0.5, shininess)
    I_gl, lit_gl = _run_shade_check(gl_ctx, X, N, grey, lights, *args, model)
    I = shade.phong(X32, N32, lights32, *args)
    lit = shade.combine(g32, I, model)
    keep = ~_near_a_switch(X32, N32, lights32)
    assert keep.sum() > 0.99 * len(X)
    assert np.isfinite(I_gl).all() and np.isfinite(lit_gl).all()
    assert np.all((np.abs(I_gl - I) <= closed_forms.phong(X32, N32, lights32, *args))[keep])
    assert np.all((np.abs(lit_gl - lit) <= closed_forms.phong(X32, N32, lights32, *args, grey=g32, model=model))[keep])
    assert np.ptp(I) > 0.5                                       # the scene is not trivially dark


@pytest.mark.gl
def test_glsl_specular_at_shininess_400_stays_within_its_bound(gl_ctx):
    """The specular term alone (I_a = k_r = 0), shininess 400 — the shader's exp(r·log(1 − s))
    with s = |R − V|²/2, the form whose float32 error glsim.check.closed_forms.phong follows — per
    point within that bound, over a thousand points above half the peak."""
    rng = np.random.default_rng(11)
    X, N, lights = _random_scene(rng, 20000)
    X32, N32 = (a.astype(np.float32).astype(float) for a in (X, N))
    lights32 = LightArrays(*(getattr(lights, f).astype(np.float32).astype(float) for f in
                             ("pos", "dir", "intensity", "attenuation", "cos_cutoff", "cos_inner")))
    I_gl, _ = _run_shade_check(gl_ctx, X, N, np.zeros(len(X)), lights, 0.0, 0.0, 1.0, 400.0, "additive")
    I = shade.phong(X32, N32, lights32, 0.0, 0.0, 1.0, 400.0)
    keep = ~_near_a_switch(X32, N32, lights32)
    assert (keep & (I > 0.5 * I.max())).sum() > 1000                # many points at the highlight
    bound = closed_forms.phong(X32, N32, lights32, 0.0, 0.0, 1.0, 400.0)
    assert np.all((np.abs(I_gl - I) <= bound)[keep])
