"""Quadratic elements (issue 14 §1): Q8, Q9, T6 surfaces and the outer faces of hex20, hex27,
tet10 and wedge15 solids, against closed forms.

The specimen is the paraboloid z = ZC + A·x² + C·y² (or the parabolic cylinder, C = 0) over
a W0 × H0 mm rectangle, meshed on a lattice affine in (x, y): a quadratic element through
lattice nodes represents it exactly (Q8/Q9: x, y affine in (ξ, η) and z quadratic; T6: total
degree 2), so the ray of every pixel meets the mesh where it meets the analytic surface, in
closed form (:func:`closed_form`). Load step 1 translates by SHIFT and adds
uz = B·x² + D·x·y (also quadratic, so exact too).

Tolerances (numbers measured when written are in docs/quadratic.md):
- oracle exact: X within 1e-9 mm of the closed form; coverage = the analytic footprint;
- oracle q4 and fast: X within 5e-3 mm (their mapping error, measured ≈ 1e-3 mm);
- GL exact / q4 vs the oracle: same coverage and elements everywhere, X and the reference
  point within 1e-9, grey within 1e-6 (fp64 builds; fp32 and supersampled: 1e-4);
- GL fast vs oracle fast: element ids agree on ≥ 99.5 % of common pixels, X within 1e-4 mm
  where they agree (GL's fast reference point is float32), grey levels mean |Δ| ≤ 1e-4, at most 0.5 % of pixels beyond 1e-3.
"""
import warnings
from pathlib import Path

import meshio
import numpy as np
import pytest

from glsim.check import closed_forms, oracle_maps
from glsim.errors import RenderWarning, SceneError
from glsim.io.fe import load_mesh, load_series
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen
from glsim.scene import quadratic as qd
from glsim.scene.camera import Camera
from glsim.scene.mesh import Mesh

CAM = Camera(name="c", size=(96, 80), fx=1000.0, fy=1000.0, cx=47.3, cy=39.6)
ZC, W0, H0 = 400.0, 30.0, 24.0
A, C = 0.01, 0.006
B, D = 0.004, -0.002
SHIFT = np.array([0.21, -0.13, 0.37])
BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


# --- meshes on a lattice ------------------------------------------------------------------------

def lattice(nx, ny, nz=0, a=A, c=C, thickness=4.0, dy=None):
    """Nodes of the (2nx+1) × (2ny+1) × (2nz+1) lattice over the rectangle, z = ZC + a x² + c y²
    (+ the depth k·thickness/(2nz)), and index(i, j, k). ``dy`` (rows, cols) → mm moves the
    lattice's y before z is computed (off-centre mid-side nodes)."""
    xs, ys = np.linspace(-W0 / 2, W0 / 2, 2 * nx + 1), np.linspace(-H0 / 2, H0 / 2, 2 * ny + 1)
    ks = np.arange(2 * nz + 1)
    K, J, I = np.meshgrid(ks, np.arange(2 * ny + 1), np.arange(2 * nx + 1), indexing="ij")
    x, y = xs[I], ys[J]
    if dy is not None:
        y = y + dy(J, I)
    z = ZC + a * x ** 2 + c * y ** 2 + (K * thickness / max(2 * nz, 1))
    nodes = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    index = np.arange(x.size).reshape(x.shape)
    return nodes, lambda i, j, k=0: index[k, j, i]


def q8_cells(nx, ny, at, nine=False):
    cells = []
    for j in range(ny):
        for i in range(nx):
            r, c = 2 * j, 2 * i
            row = [at(c, r), at(c + 2, r), at(c + 2, r + 2), at(c, r + 2),
                   at(c + 1, r), at(c + 2, r + 1), at(c + 1, r + 2), at(c, r + 1)]
            cells.append(row + [at(c + 1, r + 1)] if nine else row)
    return np.array(cells)


def t6_cells(nx, ny, at):
    cells = []
    for j in range(ny):
        for i in range(nx):
            r, c = 2 * j, 2 * i
            cells.append([at(c, r), at(c + 2, r), at(c + 2, r + 2), at(c + 1, r), at(c + 2, r + 1), at(c + 1, r + 1)])
            cells.append([at(c, r), at(c + 2, r + 2), at(c, r + 2), at(c + 1, r + 1), at(c + 1, r + 2), at(c, r + 1)])
    return np.array(cells)


def lattice_cubes(nx, ny):
    """The one layer's cubes: per cell (row-major), its 8 corners' lattice indices (i, j, k) in
    VTK's (and Exodus's) order, front face (k = 0) first."""
    for j in range(ny):
        for i in range(nx):
            o = np.array([2 * i, 2 * j, 0])
            yield [o + 2 * np.array(v) for v in ((0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0),
                                                  (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1))]


def solid_cells(kind, nx, ny, at):
    """Cells of one layer of solids (VTK node order) on the lattice, front face at k = 0."""
    def mid(p, q):
        return tuple((np.array(p) + np.array(q)) // 2)

    out = []
    for cube in lattice_cubes(nx, ny):
        if kind in ("hexahedron20", "hexahedron27"):
            corners = cube
            edges = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]
            pts = corners + [mid(corners[a], corners[b]) for a, b in edges]
            if kind == "hexahedron27":
                faces = [(0, 3, 7, 4), (1, 2, 6, 5), (0, 1, 5, 4), (3, 2, 6, 7), (0, 1, 2, 3), (4, 5, 6, 7)]
                pts += [tuple(sum(np.array(corners[f]) for f in face) // 4) for face in faces]
                pts += [tuple(sum(np.array(c) for c in corners) // 8)]
            out.append([at(*p) for p in pts])
        elif kind == "wedge15":
            for tri in ((0, 1, 2), (0, 2, 3)):
                corners = [cube[t] for t in tri] + [cube[t + 4] for t in tri]
                edges = [(0, 1), (1, 2), (2, 0), (3, 4), (4, 5), (5, 3), (0, 3), (1, 4), (2, 5)]
                out.append([at(*p) for p in corners + [mid(corners[a], corners[b]) for a, b in edges]])
        else:   # tetra10: the 6 Kuhn tetrahedra around the cube's diagonal 0–6
            for path in ((1, 2), (3, 2), (1, 5), (4, 5), (3, 7), (4, 7)):
                corners = [cube[0], cube[path[0]], cube[path[1]], cube[6]]
                edges = [(0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3)]
                out.append([at(*p) for p in corners + [mid(corners[a], corners[b]) for a, b in edges]])
    return np.array(out)


def step1(nodes, d=D):
    """Load step 1: the displacement (N, 3) — SHIFT plus uz = B x² + d x y."""
    u = np.broadcast_to(SHIFT, nodes.shape).copy()
    u[:, 2] += B * nodes[:, 0] ** 2 + d * nodes[:, 0] * nodes[:, 1]
    return u


def surface_mesh(kind, nx=4, ny=3, c=C, dy=None, deform=True, d=D):
    nodes, at = lattice(nx, ny, c=c, dy=dy)
    if kind == "quad8":
        cells, centre = q8_cells(nx, ny, at), qd.CENTRE_Q8
        patches = np.concatenate([cells, np.full((len(cells), 1), centre)], 1)
    elif kind == "quad9":
        patches = q8_cells(nx, ny, at, nine=True)
    else:
        t = t6_cells(nx, ny, at)
        patches = np.stack([t[:, 0], t[:, 1], t[:, 2], t[:, 2], t[:, 3], t[:, 4], t[:, 2], t[:, 5],
                            np.full(len(t), qd.CENTRE_T6)], 1)
    steps = (np.zeros_like(nodes), step1(nodes, d)) if deform else ()
    return Mesh(nodes, patches[:, :4], np.arange(1, len(nodes) + 1), np.arange(1, len(patches) + 1), steps,
                patches=patches)


def scene():
    return Scene(cameras=(CAM,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))


# --- closed forms --------------------------------------------------------------------------------

def rays(points=None):
    """Normalized ray coordinates (u, v) of every pixel centre, or of ``points`` (N, 2) px."""
    W, H = CAM.size
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1) if points is None else points
    return (q[..., 0] - CAM.cx) / CAM.fx, (q[..., 1] - CAM.cy) / CAM.fy


def closed_form(a=A, c=C, deformed=True, d=D, points=None):
    """Per pixel (or point of ``points``): the undeformed material point (x, y) and
    X_undeformed, X_deformed where the ray meets the (deformed) surface
    X = (x, y, ZC + a x² + c y²) + u(x, y)."""
    u, v = rays(points)
    t = SHIFT if deformed else np.zeros(3)
    b_, d_ = (B, d) if deformed else (0.0, 0.0)
    a2, c2 = a + b_, c
    # s = Z0 + a2 (us − tx)² + c2 (vs − ty)² + d (us − tx)(vs − ty), Z0 = ZC + tz
    qa = a2 * u * u + c2 * v * v + d_ * u * v
    qb = -2 * a2 * u * t[0] - 2 * c2 * v * t[1] - d_ * (u * t[1] + v * t[0]) - 1
    qc = ZC + t[2] + a2 * t[0] ** 2 + c2 * t[1] ** 2 + d_ * t[0] * t[1]
    s = 2 * qc / (-qb + np.sqrt(qb * qb - 4 * qa * qc))
    Xd = np.stack([u * s, v * s, s], -1)
    x, y = Xd[..., 0] - t[0], Xd[..., 1] - t[1]
    Xu = np.stack([x, y, ZC + a * x ** 2 + c * y ** 2], -1)
    return x, y, Xu, Xd


def footprint(x, y, margin=1e-6):
    """Pixels whose material point is inside the rectangle, and those within ``margin`` mm of
    its outline (left out of coverage comparisons)."""
    inside = (np.abs(x) < W0 / 2) & (np.abs(y) < H0 / 2)
    near = (np.abs(np.abs(x) - W0 / 2) <= margin) | (np.abs(np.abs(y) - H0 / 2) <= margin)
    return inside, near


def check_against_closed_form(truth, tol, a=A, c=C, deformed=True, min_pixels=3000, d=D):
    x, y, Xu, Xd = closed_form(a, c, deformed, d)
    inside, near = footprint(x, y)
    m = truth.mask
    assert m.sum() >= min_pixels
    assert (m == inside)[~near].all(), "coverage differs from the analytic footprint"
    err_d = np.abs(truth.X_deformed[m] - Xd[m]).max()
    err_u = np.abs(truth.X_undeformed[m] - Xu[m]).max()
    assert err_d <= tol and err_u <= tol, (err_d, err_u)
    return err_d, err_u


# --- the oracle against closed forms ----------------------------------------------------------

@pytest.mark.parametrize("kind", ["quad8", "quad9", "triangle6"])
def test_oracle_exact_truth_is_the_closed_form(kind):
    """Ray against the curved patch (Newton from the 2×2 sub-quads): X within 1e-9 mm, both
    states, on Q8, Q9 and T6 meshes of the paraboloid; no NaN anywhere."""
    with Renderer(scene(), "cpu", mesh=surface_mesh(kind)) as r:
        for step in (0, 1):
            res = r.render(0, step, truth=True, mode="exact")
            check_against_closed_form(res.truth, 1e-9, deformed=step == 1)
            assert np.isfinite(res.image).all()
            m = res.truth.mask
            assert np.isfinite(res.truth.xi[m]).all() and (np.abs(res.truth.xi[m]) <= 1 + 1e-9).all()


def test_oracle_truth_reports_the_elements_own_coordinates():
    """Q8 on the lattice: x is affine in ξ per element, so ξ = 2(x − x_left)/Δx − 1 exactly;
    T6: the collapsed patch's (ξ, η), λa = (1−ξ)(1−η)/4, λb = (1+ξ)(1−η)/4, λc = (1+η)/2."""
    nx, ny = 4, 3
    dx, dyy = W0 / nx, H0 / ny
    x, y, _, _ = closed_form(deformed=False)
    with Renderer(scene(), "cpu", mesh=surface_mesh("quad8", nx, ny)) as r:
        t = r.render(0, 0, truth=True, mode="exact").truth
    m = t.mask
    col, row = (t.element[m] - 0) % nx, (t.element[m] - 0) // nx
    assert np.abs(t.xi[m] - (2 * (x[m] + W0 / 2 - col * dx) / dx - 1)).max() <= 1e-9
    assert np.abs(t.eta[m] - (2 * (y[m] + H0 / 2 - row * dyy) / dyy - 1)).max() <= 1e-9
    with Renderer(scene(), "cpu", mesh=surface_mesh("triangle6", nx, ny)) as r:
        t = r.render(0, 0, truth=True, mode="exact").truth
    m = t.mask
    xi, eta, e = t.xi[m], t.eta[m], t.element[m]
    lb, lc = (1 + xi) * (1 - eta) / 4, (1 + eta) / 2          # barycentrics of corners b, c
    cell = e // 2
    x0, y0 = -W0 / 2 + (cell % nx) * dx, -H0 / 2 + (cell // nx) * dyy
    first = e % 2 == 0          # corners (x0, y0), (x0+dx, y0), (x0+dx, y0+dy) / (x0, y0), (x0+dx, y0+dy), (x0, y0+dy)
    xb = np.where(first, x0 + dx * (lb + lc), x0 + dx * lb)
    yb = np.where(first, y0 + dyy * lc, y0 + dyy * (lb + lc))
    assert np.abs(xb - x[m]).max() <= 1e-9 and np.abs(yb - y[m]).max() <= 1e-9


@pytest.mark.parametrize("kind", ["quad8", "triangle6"])
def test_off_centre_mid_side_nodes(kind):
    """Mid-side nodes of the edges along y moved 0.3 of the half-edge along the edge (on the
    parabolic cylinder z = ZC + A x², which the moved mesh still represents exactly; step 1
    without the x·y term, which y quadratic in the T6's λ would make cubic): exact truth within
    1e-9 mm of the closed form, and no element named folded."""
    half = H0 / 3 / 2
    dy = lambda J, I: np.where((J % 2 == 1) & (I % 2 == 0), 0.3 * half, 0.0)   # noqa: E731
    mesh = surface_mesh(kind, c=0.0, dy=dy, d=0.0)
    with Renderer(scene(), "cpu", mesh=mesh) as r, warnings.catch_warnings():
        warnings.simplefilter("error", RenderWarning)
        for step in (0, 1):
            check_against_closed_form(r.render(0, step, truth=True, mode="exact").truth, 1e-9, c=0.0,
                                      deformed=step == 1, d=0.0)


def test_folded_element_is_named_and_stays_finite():
    """One mid-side node moved 0.8 of the half-edge (past the quarter point): the element
    folds; the render names it in a RenderWarning and has no NaN; pixels elsewhere keep their
    closed-form truth."""
    half = H0 / 3 / 2
    nx, ny = 4, 3
    dy = lambda J, I: np.where((J == 1) & (I == 2), 0.8 * half, 0.0)   # noqa: E731  (elements 1 and 2 share it)
    mesh = surface_mesh("quad8", nx, ny, c=0.0, dy=dy)
    with Renderer(scene(), "cpu", mesh=mesh) as r:
        with pytest.warns(RenderWarning, match=r"elements 1, 2 are folded"):
            res = r.render(0, 0, truth=True, mode="exact")
        for mode in ("q4", "fast"):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RenderWarning)
                assert np.isfinite(r.render(0, 0, truth=True, mode=mode).image).all()
    assert np.isfinite(res.image).all()
    t = res.truth
    assert np.isfinite(t.X_deformed[t.mask]).all()
    _, _, _, Xd = closed_form(c=0.0, deformed=False)
    far = t.mask & ~np.isin(t.element, [0, 1])
    assert np.abs(t.X_deformed[far] - Xd[far]).max() <= 1e-9


def test_q4_and_fast_modes_error_is_bounded():
    """q4 (the paper's inverse mapping with the Q9 shape functions in the image) and fast
    (4 × 4 linear pieces per element): X within 5e-3 mm of the closed form; same coverage
    away from the outline."""
    with Renderer(scene(), "cpu", mesh=surface_mesh("quad8")) as r:
        for mode in ("q4", "fast"):
            t = r.render(0, 1, truth=True, mode=mode).truth
            x, y, Xu, Xd = closed_form()
            inside, _ = footprint(x, y, 0.5)
            m = t.mask
            assert (m == inside)[np.abs(np.abs(x) - W0 / 2) > 0.5].sum() > 3000
            assert np.abs(t.X_deformed[m] - Xd[m]).max() <= 5e-3, mode


def test_q8_against_fine_q4_converges():
    """The same paraboloid meshed in Q4 with k × k elements per Q8 element (exact mode, the
    established bilinear path): the largest X difference on common pixels falls like 1/k²."""
    nx, ny = 3, 2
    with Renderer(scene(), "cpu", mesh=surface_mesh("quad8", nx, ny, deform=False)) as r:
        ref = r.render(0, 0, truth=True, mode="exact").truth
    errs = []
    for k in (1, 2, 4, 8):
        xs, ys = np.linspace(-W0 / 2, W0 / 2, nx * k + 1), np.linspace(-H0 / 2, H0 / 2, ny * k + 1)
        X, Y = np.meshgrid(xs, ys)
        nodes = np.stack([X.ravel(), Y.ravel(), ZC + A * X.ravel() ** 2 + C * Y.ravel() ** 2], 1)
        idx = np.arange(X.size).reshape(X.shape)
        quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
        q4 = Mesh(nodes, quads, np.arange(1, len(nodes) + 1), np.arange(1, len(quads) + 1))
        with Renderer(scene(), "cpu", mesh=q4) as r:
            t = r.render(0, 0, truth=True, mode="exact").truth
        both = t.mask & ref.mask
        errs.append(np.abs(t.X_deformed[both] - ref.X_deformed[both]).max())
    errs = np.array(errs)
    assert (np.diff(errs) < 0).all(), errs
    assert errs[-1] <= errs[0] / 30, errs   # 1/k² would be 1/64


# --- GL ----------------------------------------------------------------------------------------

@pytest.mark.gl
def test_gl_fast_matches_the_oracle_fast(gl_ctx):
    """GL fast mode draws the same linear pieces as the oracle's fast mode."""
    mesh = surface_mesh("quad8")
    with Renderer(scene(), "gl", ctx=gl_ctx, mesh=mesh) as g, Renderer(scene(), "cpu", mesh=mesh) as c:
        a = g.render(0, 1, truth=True, mode="fast")
        b = c.render(0, 1, truth=True, mode="fast")
    both = a.truth.mask & b.truth.mask
    same = both & (a.truth.element == b.truth.element)
    assert both.sum() > 3000 and same.sum() >= 0.995 * both.sum()
    # GL's fast truth starts from its float32 reference point: X within fast's float32 bound
    # (glsim.check.closed_forms) per pixel
    dX = np.linalg.norm(a.truth.X_deformed - b.truth.X_deformed, axis=-1)
    assert (dX <= closed_forms.fast_bound(a.camera.fx, b.truth.X_deformed, b.truth.mask))[same].all(), dX[same].max()
    d = np.abs(a.image.astype(float) - b.image.astype(float))
    assert d.mean() <= 1e-4 and (d > 1e-3).mean() <= 0.005, (d.mean(), (d > 1e-3).mean())
    check = closed_form()[3]
    assert np.abs(a.truth.X_deformed[a.truth.mask] - check[a.truth.mask]).max() <= 5e-3


@pytest.mark.gl
@pytest.mark.parametrize("kind", ["quad8", "triangle6"])
@pytest.mark.parametrize("mode", ["exact", "q4"])
def test_gl_curved_modes_match_the_oracle(gl_ctx, kind, mode):
    """GL exact / q4 (Newton on the patch's 9 nodes in the fragment shader, from the piece's
    roots): the same coverage and elements as the oracle on every pixel, X within 1e-9 mm of
    it (and, exact, of the closed form); grey levels within glsim.check.closed_forms.grey: what
    float32 allows the reference sample at the same point (both images stored as float32) in
    fp64 builds, plus the box filter's float32 mean at 2×2 samples; fp32 builds, whose reference
    points move by their own Δ (the truth maps'): plus |∇I|·|Δ| and a second-order term."""
    from glsim.imaging import interp

    mesh = surface_mesh(kind)
    with Renderer(scene(), "gl", ctx=gl_ctx, mesh=mesh) as g, Renderer(scene(), "cpu", mesh=mesh) as c:
        method = c.scene.render.interpolation
        coeffs = interp.prepare(c.reference.image, method, np.float64)
        M = float(np.abs(coeffs).max())
        sample = closed_forms.grey(method, M, 0.0, 0.0)   # (the same points)
        for step in (0, 1):
            a = g.render(0, step, truth=True, mode=mode)
            b = c.render(0, step, truth=True, mode=mode)
            assert (a.truth.mask == b.truth.mask).all() and a.truth.mask.sum() > 3000
            m = a.truth.mask
            assert (a.truth.element[m] == b.truth.element[m]).all()
            for f in ("X_undeformed", "X_deformed", "ref_uv"):
                assert np.abs(getattr(a.truth, f)[m] - getattr(b.truth, f)[m]).max() <= 1e-9, f
            assert np.abs(a.image.astype(float) - b.image).max() <= sample
            if mode == "exact":
                check_against_closed_form(a.truth, 1e-9, deformed=step == 1)
        a, b = g.render(0, 1, mode=mode, samples_per_pixel=4), c.render(0, 1, mode=mode, samples_per_pixel=4)
        assert np.abs(a.image.astype(float) - b.image).max() <= closed_forms.grey(method, M, 0.0, 0.0, 4)
        a, b = g.render(0, 1, truth=True, mode=mode, precision="fp32"), c.render(0, 1, truth=True, mode=mode)
        m = a.truth.mask & b.truth.mask
        d = np.linalg.norm(a.truth.ref_uv - b.truth.ref_uv, axis=-1)
        grad = closed_forms.sample_gradient(method, coeffs, b.truth.ref_uv, m)
        assert np.all((np.abs(a.image.astype(float) - b.image) <= closed_forms.grey(method, M, grad, d))[m])


@pytest.mark.gl
def test_gl_folded_element_is_named_and_stays_finite(gl_ctx):
    """The folded mesh of test_folded_element_is_named_and_stays_finite on GL: named, no NaN;
    where the fold gives a ray several roots, or folds the elements' edge over their
    neighbours 4, 5 (same depth), GL and the oracle may pick different ones (GL starts from
    each piece, the oracle from the 2×2 sub-quads): at most 20 such pixels, all there."""
    half = H0 / 3 / 2
    dy = lambda J, I: np.where((J == 1) & (I == 2), 0.8 * half, 0.0)   # noqa: E731
    mesh = surface_mesh("quad8", 4, 3, c=0.0, dy=dy)
    with Renderer(scene(), "gl", ctx=gl_ctx, mesh=mesh) as g, Renderer(scene(), "cpu", mesh=mesh) as c:
        for mode in ("exact", "q4"):
            with pytest.warns(RenderWarning, match=r"elements 1, 2 are folded"):
                a = g.render(0, 0, truth=True, mode=mode)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RenderWarning)
                b = c.render(0, 0, truth=True, mode=mode)
            assert np.isfinite(a.image).all()
            differ = (a.truth.mask != b.truth.mask) | (a.truth.element != b.truth.element)
            differ |= np.abs(a.image.astype(float) - b.image) > 1e-3
            assert differ.sum() <= 20 and np.isin(b.truth.element[differ & b.truth.mask], [0, 1, 4, 5]).all()


@pytest.mark.gl
@pytest.mark.parametrize("centre", ["quad9", "quad8"])
def test_gl_matches_the_oracle_on_a_strongly_curved_tilted_distorted_cylinder(gl_ctx, centre):
    """Hard case: a circular cylinder of radius 12 mm, 162° of it in 3 × 2 elements (54° each),
    tilted by 20° and 25°, seen through strong distortion (k1 = −0.25, k2 = 0.1, p1 = 0.001),
    with its limb (rays grazing the patches, meeting each twice) inside the image: GL and the
    oracle search the same Newton starts and agree on every pixel — coverage, element, X within
    1e-9 mm, grey within 1e-6 — in exact and q4."""
    from glsim.scene.camera import Distortion

    ax, ay = np.radians([20.0, 25.0])
    Rx = np.array([[1, 0, 0], [0, np.cos(ax), -np.sin(ax)], [0, np.sin(ax), np.cos(ax)]])
    Ry = np.array([[np.cos(ay), 0, np.sin(ay)], [0, 1, 0], [-np.sin(ay), 0, np.cos(ay)]])
    th, ys = np.linspace(-0.45 * np.pi, 0.45 * np.pi, 7), np.linspace(-10, 10, 5)
    T, Y = np.meshgrid(th, ys)
    nodes = np.stack([12 * np.sin(T).ravel(), Y.ravel(), -12 * np.cos(T).ravel()], 1) @ (Ry @ Rx).T + [1, -0.5, 120]
    at = np.arange(T.size).reshape(T.shape)
    p = np.array([[at[r, c], at[r, c + 2], at[r + 2, c + 2], at[r + 2, c], at[r, c + 1], at[r + 1, c + 2],
                   at[r + 2, c + 1], at[r + 1, c], at[r + 1, c + 1] if centre == "quad9" else qd.CENTRE_Q8]
                  for r in (0, 2) for c in (0, 2, 4)])
    u = np.zeros_like(nodes)
    u[:, 2] = 0.3 + 0.001 * nodes[:, 0] ** 2
    mesh = Mesh(nodes, p[:, :4], np.arange(1, len(nodes) + 1), np.arange(1, len(p) + 1), (np.zeros_like(nodes), u),
                patches=p)
    cam = Camera(name="c", size=(160, 120), fx=700.0, fy=700.0, cx=80.3, cy=59.6,
                 distortion=Distortion(k1=-0.25, k2=0.1, p1=0.001))
    sc = Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    with Renderer(sc, "gl", ctx=gl_ctx, mesh=mesh) as g, Renderer(sc, "cpu", mesh=mesh) as c, \
            warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)     # grazing elements
        for mode in ("exact", "q4"):
            a, b = g.render(0, 1, truth=True, mode=mode), c.render(0, 1, truth=True, mode=mode)
            m = a.truth.mask
            assert (m == b.truth.mask).all() and m.sum() > 10000
            assert (a.truth.element[m] == b.truth.element[m]).all()
            assert np.abs(a.truth.X_deformed[m] - b.truth.X_deformed[m]).max() <= 1e-9
            assert np.abs(a.image.astype(float) - b.image).max() <= 1e-6


CROSS_CAM = Camera(name="c", size=(96, 72), fx=100.0, fy=100.0, cx=47.3, cy=35.6)


def px_distance(f):
    """Distance (px) of each pixel centre to the zero line of a smooth per-pixel function f, to
    first order (as tests/hard/test_hard_geometry.py)."""
    gy, gx = np.gradient(f)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(f) / np.hypot(gx, gy)


@pytest.mark.parametrize("mode", ["exact", "q4"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_quadratic_elements_crossing_the_camera_plane(backend, mode, ctx_for):
    """The hard case of tests/hard/test_hard_geometry.py with 8 × 4 Q9 elements: an 80 × 16 mm
    plate at 300 mm mapped at step 1 onto the plane z = 30 + 3y (x' = x, y' = 3y − 2), one row
    of elements (material y in [−4, 0]) crossing the camera plane. No NaN; nothing drawn from
    behind the camera; away (1 px) from the outline the mask is the closed form's — exact also
    shows the crossing row's part in front of the camera (from its pieces' covers, as GL), q4
    drops that row (warned); exact X within 1e-9 mm of the ray/plane intersection."""
    nx, ny = 8, 4
    xs, ys = np.linspace(-40, 40, 2 * nx + 1), np.linspace(-8, 8, 2 * ny + 1)
    X, Y = np.meshgrid(xs, ys)
    nodes = np.stack([X.ravel(), Y.ravel(), np.full(X.size, 300.0)], 1)
    at = np.arange(X.size).reshape(X.shape).T
    p = q8_cells(nx, ny, lambda i, j: at[i, j], nine=True)
    moved = nodes.copy()
    moved[:, 1] = 3 * nodes[:, 1] - 2
    moved[:, 2] = 30 + 3 * moved[:, 1]
    mesh = Mesh(nodes, p[:, :4], np.arange(1, len(nodes) + 1), np.arange(1, len(p) + 1),
                (np.zeros_like(nodes), moved - nodes), patches=p)
    sc = Scene(cameras=(CROSS_CAM,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    W, H = CROSS_CAM.size
    q = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)), -1)
    xn, yn = (q[..., 0] - CROSS_CAM.cx) / CROSS_CAM.fx, (q[..., 1] - CROSS_CAM.cy) / CROSS_CAM.fy
    with np.errstate(divide="ignore"):
        t_ray = 30 / (1 - 3 * yn)
    Xd = np.stack([xn * t_ray, yn * t_ray, t_ray], -1)
    mx, my = Xd[..., 0], (Xd[..., 1] + 2) / 3
    with Renderer(sc, backend, ctx=ctx_for(backend), mesh=mesh) as r, warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always", RenderWarning)
        res = r.render(0, 1, truth=True, mode=mode)
    t = res.truth
    assert np.isfinite(res.image).all() and np.isfinite(t.X_deformed[t.mask]).all()
    assert (t_ray < 0).sum() > 200 and not t.mask[t_ray < 0].any()
    assert (t.X_deformed[t.mask][:, 2] > 0).all()
    want = (t_ray > 0) & (np.abs(mx) < 40) & (np.abs(my) < 8)
    lines = [mx - 40, mx + 40, my - 8, my + 8]
    if mode == "q4":
        want &= ~((my > -4) & (my < 0))
        lines += [my + 4, my]
        assert any("cross the camera plane" in str(x.message) for x in w)
    sure = ((t_ray > 0) & np.all([px_distance(f) > 1.0 for f in lines], axis=0)) | (t_ray < 0)
    assert want[sure & (my > -4) & (my < 0)].any() == (mode == "exact")
    assert np.array_equal(t.mask[sure], want[sure]), int((t.mask[sure] != want[sure]).sum())
    if mode == "exact":
        assert np.abs(t.X_deformed[t.mask] - Xd[t.mask]).max() <= 1e-9


@pytest.mark.parametrize("mode", ["exact", "q4"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_far_from_origin_loses_no_precision(backend, mode, ctx_for):
    """Camera and specimen translated by (5e4, −3e4, 2e5) mm (the Q4 hard case): the truth in
    the camera frame as at the origin — exact within 1e-9 mm of the closed form, q4 within
    1e-9 mm of the oracle's q4 at the origin."""
    far = np.array([5e4, -3e4, 2e5])
    mesh = surface_mesh("quad8")
    moved = Mesh(mesh.nodes + far, mesh.quads, mesh.node_labels, mesh.element_labels, mesh.displacements,
                 patches=mesh.patches)
    cam = Camera(name="c", size=CAM.size, fx=CAM.fx, fy=CAM.fy, cx=CAM.cx, cy=CAM.cy, t=tuple(-far))
    sc = Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    with Renderer(sc, backend, ctx=ctx_for(backend), mesh=moved) as r:
        t = r.render(0, 1, truth=True, mode=mode).truth
    if mode == "exact":
        check_against_closed_form(t, 1e-9)
    else:
        with Renderer(scene(), "cpu", mesh=mesh) as c:
            ref = c.render(0, 1, truth=True, mode=mode).truth
        assert (t.mask == ref.mask).all()
        assert np.abs(t.X_deformed[t.mask] - ref.X_deformed[t.mask]).max() <= 1e-9


# --- files -------------------------------------------------------------------------------------

def _write_and_read(path, nodes, cells, kind, fmt=None):
    u = step1(nodes)
    meshio.write(path, meshio.Mesh(nodes, [(kind, cells)], point_data={"u": u}), file_format=fmt)
    return load_mesh(path, point_data_steps=["u"])


@pytest.mark.parametrize("kind,suffix,fmt", [("quad8", ".vtu", None), ("quad9", ".inp", None),
                                              ("triangle6", ".msh", "gmsh22"), ("quad8", ".inp", None)])
def test_shell_files_through_meshio(tmp_path, kind, suffix, fmt):
    """quad8 / quad9 / triangle6 written by meshio (VTU, Abaqus, Gmsh) and read back: exact
    truth of step 1 (point-data displacement) within 1e-9 mm of the closed form."""
    nodes, at = lattice(4, 3)
    cells = t6_cells(4, 3, at) if kind == "triangle6" else q8_cells(4, 3, at, nine=kind == "quad9")
    if suffix == ".inp":            # Abaqus .inp holds no point data: the step comes as a CSV
        meshio.write(tmp_path / f"m{suffix}", meshio.Mesh(nodes, [(kind, cells)]))
        csv = tmp_path / "u.csv"
        csv.write_text("".join(f"{k + 1};{a};{b};{c}\n" for k, (a, b, c) in enumerate(step1(nodes))))
        mesh = load_mesh(tmp_path / f"m{suffix}", csv_files=[csv])
    else:
        mesh = _write_and_read(tmp_path / f"m{suffix}", nodes, cells, kind, fmt)
    assert mesh.is_quadratic and mesh.n_elements == len(cells) and mesh.n_steps == 2
    with Renderer(scene(), "cpu", mesh=mesh) as r:
        check_against_closed_form(r.render(0, 1, truth=True, mode="exact").truth, 1e-9)


@pytest.mark.parametrize("kind,suffix,fmt", [("hexahedron20", ".vtu", None), ("hexahedron20", ".inp", None),
                                              ("hexahedron27", ".vtu", None), ("hexahedron27", ".msh", "gmsh22"),
                                              ("tetra10", ".vtu", None), ("tetra10", ".msh", "gmsh22"),
                                              ("tetra10", ".inp", None), ("wedge15", None, None)])
def test_solid_outer_faces_through_meshio(tmp_path, kind, suffix, fmt):
    """One layer of quadratic solids whose front face is the paraboloid: the outer faces are
    extracted (front face curved as the closed form: exact truth within 1e-9 mm), oriented
    outward (normals of the front face towards the camera), none folded."""
    nx, ny = 3, 2
    nodes, at = lattice(nx, ny, nz=1)
    cells = solid_cells(kind, nx, ny, at)
    if suffix is None:   # meshio 5.3.5 cannot hold wedge15 cells (KeyError); the face table, in memory
        from types import SimpleNamespace
        from glsim.io.meshfiles import surface_from_cells
        quads, labels, patches = surface_from_cells(tmp_path, SimpleNamespace(cells=[SimpleNamespace(type=kind, data=cells)]),
                                                    nodes, [np.arange(1, len(cells) + 1)])
        mesh = Mesh(nodes, quads, np.arange(1, len(nodes) + 1), labels, patches=patches)
    else:
        path = tmp_path / f"s{suffix}"
        meshio.write(path, meshio.Mesh(nodes, [(kind, cells)]), file_format=fmt)
        mesh = load_mesh(path)
    assert mesh.is_quadratic
    P = qd.patch_points(mesh.patches, mesh.nodes)
    assert not qd.folded(P).any()
    centre = qd.evaluate(P, 0.0, 0.0)
    front = np.abs(centre[:, 2] - (ZC + A * centre[:, 0] ** 2 + C * centre[:, 1] ** 2)) < 1e-9
    normal = np.cross(*(np.einsum("mi,mid->md", d, P) for d in qd.shape_derivatives(np.zeros(len(P)),
                                                                                     np.zeros(len(P)))))
    assert front.sum() == (nx * ny * (2 if kind in ("tetra10", "wedge15") else 1))
    assert (normal[front, 2] < 0).all()          # outward = towards the camera at the origin (−z)
    with Renderer(scene(), "cpu", mesh=mesh) as r, warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)   # side walls are seen edge-on (grazing)
        check_against_closed_form(r.render(0, 0, truth=True, mode="exact").truth, 1e-9, deformed=False)


def test_abaqus_c3d20r_keyword(tmp_path):
    """An Abaqus file with *ELEMENT, TYPE=C3D20R (reduced integration, the usual specimen
    element) is read as hexahedron20: its outer faces become Q8 patches."""
    nodes, at = lattice(3, 2, nz=1)
    path = tmp_path / "c3d20r.inp"
    meshio.write(path, meshio.Mesh(nodes, [("hexahedron20", solid_cells("hexahedron20", 3, 2, at))]))
    import re

    text, count = re.subn(r"TYPE=C3D20\w*", "TYPE=C3D20R", path.read_text())
    assert count == 1
    path.write_text(text)
    mesh = load_mesh(path)
    assert mesh.is_quadratic and (mesh.patches[:, 8] == qd.CENTRE_Q8).all()
    with Renderer(scene(), "cpu", mesh=mesh) as r, warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        check_against_closed_form(r.render(0, 0, truth=True, mode="exact").truth, 1e-9, deformed=False)


def test_exodus_quadratic_blocks(tmp_path):
    """Exodus II: QUAD8 written by meshio's Exodus writer (VTK order) and HEX20 in Exodus's own
    order (vertical mid-edge nodes 13–16 before the top face's 17–20, 1-based) read back."""
    nodes, at = lattice(4, 3)
    cells = q8_cells(4, 3, at)
    u = step1(nodes)
    meshio.write(tmp_path / "q8.e", meshio.Mesh(nodes, [("quad8", cells)],
                                                point_data={f"disp_{a}": u[:, k] for k, a in enumerate("xyz")}))
    mesh = load_series(tmp_path / "q8.e")
    assert mesh.n_steps == 2     # the stored (displaced) time after an undeformed step 0
    with Renderer(scene(), "cpu", mesh=mesh) as r:
        check_against_closed_form(r.render(0, 1, truth=True, mode="exact").truth, 1e-9)
    # TETRA10 (Exodus order = VTK's) through meshio's Exodus writer
    nodes, at = lattice(3, 2, nz=1)
    meshio.write(tmp_path / "t10.e", meshio.Mesh(nodes, [("tetra10", solid_cells("tetra10", 3, 2, at))],
                                                 point_data={f"disp_{a}": 0 * nodes[:, 0] for a in "xyz"}))
    mesh = load_series(tmp_path / "t10.e")
    assert mesh.is_quadratic and not qd.folded(qd.patch_points(mesh.patches, mesh.nodes)).any()
    with Renderer(scene(), "cpu", mesh=mesh) as r, warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        check_against_closed_form(r.render(0, 0, truth=True, mode="exact").truth, 1e-9, deformed=False)
    # HEX20 in Exodus node order
    nodes, at = lattice(3, 2, nz=1)
    vtk = solid_cells("hexahedron20", 3, 2, at)
    mesh = load_series(write_exodus_block(tmp_path / "h20.e", nodes, "HEX20", vtk[:, np.r_[0:12, 16:20, 12:16]]))
    assert mesh.is_quadratic and not qd.folded(qd.patch_points(mesh.patches, mesh.nodes)).any()
    with Renderer(scene(), "cpu", mesh=mesh) as r, warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        check_against_closed_form(r.render(0, 0, truth=True, mode="exact").truth, 1e-9, deformed=False)


def write_exodus_block(path, nodes, elem_type: str, cells) -> Path:
    """An Exodus II file of ``nodes`` and one block of ``cells`` (0-based, the file's order)."""
    import netCDF4
    with netCDF4.Dataset(path, "w") as ds:
        ds.createDimension("num_nodes", len(nodes))
        ds.createDimension("num_dim", 3)
        ds.createDimension("num_el_blk", 1)
        ds.createDimension("num_el_in_blk1", len(cells))
        ds.createDimension("num_nod_per_el1", cells.shape[1])
        for k, axis in enumerate("xyz"):
            ds.createVariable(f"coord{axis}", "f8", ("num_nodes",))[:] = nodes[:, k]
        conn = ds.createVariable("connect1", "i4", ("num_el_in_blk1", "num_nod_per_el1"))
        conn.elem_type = elem_type
        conn[:] = cells + 1
    return path


# SEACAS's side-node tables (nem_slice's ss_to_node_list, 1-based): HEX27 side k's corners and
# its face-centre node; WEDGE15's and HEX27's mid-edge nodes follow from them
HEX27_SIDES = {26: (1, 2, 6, 5), 25: (2, 3, 7, 6), 27: (3, 4, 8, 7), 24: (1, 5, 8, 4), 22: (1, 4, 3, 2), 23: (5, 6, 7, 8)}
HEX_EDGES = [(1, 2), (2, 3), (3, 4), (4, 1), (1, 5), (2, 6), (3, 7), (4, 8), (5, 6), (6, 7), (7, 8), (8, 5)]   # nodes 9–20
WEDGE_EDGES = [(1, 2), (2, 3), (3, 1), (1, 4), (2, 5), (3, 6), (4, 5), (5, 6), (6, 4)]                        # nodes 7–15


def exodus_solid_cells(elem_type: str, nx: int, ny: int, at) -> np.ndarray:
    """One layer of HEX27 or WEDGE15 cells on the lattice (the cells of :func:`solid_cells`) in
    Exodus's node order, built from SEACAS's tables above, not from glsim's permutation."""
    def mean(*points):
        return tuple(sum(np.array(p) for p in points) // len(points))

    out = []
    for cube in lattice_cubes(nx, ny):
        if elem_type == "HEX27":
            pts = cube + [mean(cube[a - 1], cube[b - 1]) for a, b in HEX_EDGES] + [mean(*cube)]
            pts += [mean(*(cube[n - 1] for n in HEX27_SIDES[k])) for k in range(22, 28)]
            out.append([at(*p) for p in pts])
        else:
            for tri in ((0, 1, 2), (0, 2, 3)):
                c = [cube[t] for t in tri] + [cube[t + 4] for t in tri]
                out.append([at(*p) for p in c + [mean(c[a - 1], c[b - 1]) for a, b in WEDGE_EDGES]])
    return np.array(out)


@pytest.mark.parametrize("kind,elem_type", [("hexahedron27", "HEX27"), ("wedge15", "WEDGE15")])
def test_exodus_hex27_and_wedge15_blocks(tmp_path, kind, elem_type):
    """Exodus HEX27 (centroid 21, face centres 22–27 by side) and WEDGE15 (vertical mid-edge
    nodes 10–12 before the top's) in Exodus's own order give the patches of the same cells in
    VTK's order (test_solid_outer_faces_through_meshio), and the front face's closed form."""
    from types import SimpleNamespace

    from glsim.io.meshfiles import surface_from_cells

    nodes, at = lattice(3, 2, nz=1)
    mesh = load_series(write_exodus_block(tmp_path / "s.e", nodes, elem_type, exodus_solid_cells(elem_type, 3, 2, at)))
    vtk = solid_cells(kind, 3, 2, at)
    quads, labels, patches = surface_from_cells(tmp_path, SimpleNamespace(cells=[SimpleNamespace(type=kind, data=vtk)]),
                                                nodes, [np.arange(1, len(vtk) + 1)])
    assert mesh.is_quadratic and np.array_equal(mesh.patches, patches) and np.array_equal(mesh.quads, quads)
    assert np.array_equal(mesh.element_labels, labels)
    with Renderer(scene(), "cpu", mesh=mesh) as r, warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        check_against_closed_form(r.render(0, 0, truth=True, mode="exact").truth, 1e-9, deformed=False)


# --- bad input ---------------------------------------------------------------------------------

def test_mixed_orders_are_refused(tmp_path):
    nodes, at = lattice(4, 3)
    q8 = q8_cells(4, 3, at)
    path = tmp_path / "mixed.vtu"
    meshio.write(path, meshio.Mesh(nodes, [("quad8", q8[:5]), ("quad", q8[5:, :4])]))
    with pytest.raises(SceneError, match=r"mixed\.vtu: mixes linear \(quad\) and quadratic \(quad8\) elements — "
                                         r"export the whole specimen surface at one element order"):
        load_mesh(path)


def test_missing_nodes_are_refused():
    mesh = surface_mesh("quad8", deform=False)
    bad = mesh.patches.copy()
    bad[3, 5] = mesh.n_nodes + 7
    with pytest.raises(SceneError, match=r"mesh\.patches: element 3 refers to node indices .* \(a quadratic "
                                         r"element with a missing node\?\) — give every corner and mid-side node"):
        Mesh(mesh.nodes, mesh.quads, mesh.node_labels, mesh.element_labels, patches=bad)
    with pytest.raises(SceneError, match=r"mesh\.patches: shape \(12, 8\)"):
        Mesh(mesh.nodes, mesh.quads, mesh.node_labels, mesh.element_labels, patches=bad[:, :8])


@pytest.mark.parametrize("backend", BACKENDS)
def test_lighting_on_curved_patches(backend, ctx_for):
    """Lighting in exact / q4: the point on the curved patch, the normal interpolated over the
    linear piece holding it (the pieces' corner normals, as fast mode). GL equals the oracle
    within oracle_maps.renderer_lit per pixel (its float32 arithmetic), and both draw the same pixels; the lit
    exact image is within 1e-3 mean of the lit fast one."""
    sc = scene().replace(lighting={"lights": [{"position": [30, -20, 0]}], "ambient": 0.2, "specular": 0.3,
                                   "shininess": 8.0, "combine": "multiplicative"})
    mesh = surface_mesh("triangle6")
    with Renderer(sc, backend, ctx=ctx_for(backend), mesh=mesh) as r, Renderer(sc, "cpu", mesh=mesh) as c:
        for mode in ("exact", "q4"):
            a, b = r.render(0, 1, mode=mode), c.render(0, 1, mode=mode)
            assert np.isfinite(a.image).all()
            assert np.all(np.abs(a.image.astype(float) - b.image) <= oracle_maps.renderer_lit(c, mode, 0, 1))
            assert "light" in b.stages
        lit = c.render(0, 1, mode="exact").image
        assert np.abs(lit - c.render(0, 1, mode="fast").image).mean() <= 1e-3
    with Renderer(scene(), "cpu", mesh=mesh) as unlit:
        assert np.abs(lit - unlit.render(0, 1, mode="exact").image).mean() > 1e-2


def test_paraview_mesh_series_keeps_the_quadratic_cells(tmp_path):
    """write_mesh_series writes quad8 / quad9 / triangle6 cells (ParaView draws them curved)."""
    from glsim.io.vtkfiles import write_mesh_series

    for kind in ("quad8", "quad9", "triangle6"):
        mesh = surface_mesh(kind)
        (tmp_path / kind).mkdir()
        paths = write_mesh_series(tmp_path / kind, mesh, CAM)
        back = meshio.read(paths[0])
        assert [b.type for b in back.cells] == [kind]
        assert len(back.cells[0].data) == mesh.n_elements


@pytest.mark.parametrize("kind", ["quad8", "quad9", "triangle6"])
def test_point_truth_is_the_closed_form(kind, tmp_path, monkeypatch):
    """`glsim compare`'s truth at any camera-0 pixel of the reference state: the ray met with
    the curved undeformed patch (Newton) — the closed-form material point within 1e-9 mm, its
    displacement at step 1 the analytic u(x, y); points off the footprint not valid."""
    from glsim.workflows import compare

    monkeypatch.setattr(compare, "load_scene", lambda path: scene())
    monkeypatch.setattr(compare, "specimen_mesh", lambda sc: surface_mesh(kind))
    pts = np.random.default_rng(7).uniform([0, 0], [CAM.size[0] - 1, CAM.size[1] - 1], (400, 2))
    at, cam = compare.truth_at(tmp_path, pts, 1)
    x, y, Xu, _ = closed_form(deformed=False, points=pts)
    inside, near = footprint(x, y)
    assert cam == CAM and at.step == 1 and inside.sum() > 200
    np.testing.assert_array_equal(at.valid[~near], inside[~near])
    ok = at.valid
    np.testing.assert_allclose(at.X_undeformed[ok], Xu[ok], atol=1e-9, rtol=0)
    u = np.column_stack([np.broadcast_to(SHIFT[:2], (ok.sum(), 2)),
                         SHIFT[2] + B * x[ok] ** 2 + D * x[ok] * y[ok]])
    np.testing.assert_allclose(at.displacement[ok], u, atol=1e-9, rtol=0)


def test_point_truth_finds_points_beyond_the_control_points_projections():
    """A trough z = ZC + 4x² seen from the origin: its silhouette (the ray tangent to it) at
    x = √(ZC/4) = 10 mm lies inside the elements of 7.5 < x < 15, whose rays past the
    projections of all their nodes still meet them. The candidate boxes (the projected corners
    of a 3-D box that holds the whole curved surface, glsim.scene.quadratic.surface_box) hold
    them, where a box of the nodes' projections would not: they are found, at the closed form —
    the nearer of the ray's two roots in that element (with the sub-quads' centres as Newton
    starts only where their chords are not crossed, 3 of these 50 got the farther one)."""
    from glsim.io.truth import mesh_geometry
    from glsim.scene.locate import points_truth

    a = 4.0
    mesh = trough(a)
    outer = mesh.nodes[(mesh.nodes[:, 0] >= 7.5)]
    beyond = (outer[:, 0] / outer[:, 2]).max() * CAM.fx + CAM.cx            # px: the nodes' last projection
    silhouette = CAM.cx + CAM.fx / (2 * np.sqrt(a * ZC))                     # px: the tangent ray
    assert beyond + 0.05 < silhouette
    rng = np.random.default_rng(11)
    pts = np.column_stack([rng.uniform(beyond, silhouette - 1e-4, 50), rng.uniform(28, 51, 50)])
    at = points_truth(mesh_geometry(mesh), CAM, pts, 0)
    x, y, Xu, _ = closed_form(a=a, c=0.0, deformed=False, points=pts)
    assert at.valid.all() and (np.abs(y) < H0 / 2).all()
    np.testing.assert_allclose(at.X_undeformed, Xu, atol=1e-9, rtol=0)


def trough(a: float = 4.0):
    """The Q8 mesh of the trough z = ZC + a x² (exact: z quadratic in ξ)."""
    mesh = surface_mesh("quad8", c=0.0, d=0.0, deform=False)
    nodes = mesh.nodes * [1, 1, 0] + np.column_stack([0 * mesh.nodes[:, :2], ZC + a * mesh.nodes[:, 0] ** 2])
    return Mesh(nodes, mesh.quads, mesh.node_labels, mesh.element_labels, patches=mesh.patches)


@pytest.mark.parametrize("backend", BACKENDS)
def test_exact_mode_draws_the_nearer_surface_beside_a_silhouette(backend, ctx_for):
    """The trough's silhouette 0.1 px right of pixel column 8's centres (a 16 px wide strip
    of CAM's image, cx shifted), where each ray meets its element twice: the exact mode's
    truth in that column is the nearer point, at the closed form (the oracle and GL drew the
    farther one in rows 31, 40, 48 and 49 before their Newton starts included every sub-quad's
    centre)."""
    import dataclasses

    a, shift = 4.0, 0.3 - 52             # CAM's column 60 + 0.3 px is this camera's column 8 + 0.3
    cam = dataclasses.replace(CAM, size=(16, CAM.size[1]), cx=CAM.cx + shift)
    assert abs(cam.cx + CAM.fx / (2 * np.sqrt(a * ZC)) - 8.1) < 1e-9
    sc = Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    with Renderer(sc, backend, ctx=ctx_for(backend), mesh=trough(a)) as r, warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        t = r.render(0, 0, truth=True, mode="exact").truth
    W, H = cam.size
    v, u = np.mgrid[0:H, 0:W].astype(float)
    with np.errstate(invalid="ignore"):    # the rays past the silhouette miss the trough: NaN
        x, y, Xu, _ = closed_form(a=a, c=0.0, deformed=False, points=np.stack([u - shift, v], -1))
    column = t.mask[:, 8] & (np.abs(y[:, 8]) < H0 / 2 - 0.1)
    assert column.sum() > 30
    err = np.abs(t.X_undeformed[:, 8][column] - Xu[:, 8][column]).max()
    assert err <= 1e-9, err


def test_surface_box_holds_the_patch_and_is_tight():
    """Σ|Nᵢ| ≤ LEBESGUE = 1.25² on the patch: random patches evaluated on a fine grid stay in
    their surface_box; the control points ±1 with the signs of Nᵢ at (ξ, η) = (½, ½) reach
    its edge (the bound cannot be smaller)."""
    t = np.linspace(-1, 1, 41)
    xi, eta = (g.ravel() for g in np.meshgrid(t, t))
    P = np.random.default_rng(2).normal(size=(200, 9, 3))
    lo, hi = qd.surface_box(P)
    X = qd.evaluate(P[:, None], xi[None, :], eta[None, :])                 # (200, 1681, 3)
    assert (X >= lo[:, None] - 1e-12).all() and (X <= hi[:, None] + 1e-12).all()
    signs = np.sign(qd.shape_functions(0.5, 0.5))
    worst = qd.evaluate(np.column_stack([signs, -signs, signs])[None], 0.5, 0.5)[0]
    np.testing.assert_allclose(np.abs(worst), qd.LEBESGUE, rtol=1e-15)
    np.testing.assert_allclose(qd.surface_box(np.column_stack([signs, -signs, signs])[None])[1][0], qd.LEBESGUE)


def test_render_truth_files_give_quadratic_point_truth(tmp_path):
    """End to end: a Q8 VTU rendered with truth (`glsim render --truth`'s files), then
    ``truth.load(...).at`` at every pixel centre: the rendered step-0 maps (the oracle's pixel
    boxes per element) and the point truth (boxes that hold each patch, candidates by a grid)
    find the same pixels, elements and material points; the displacement is step 1's closed
    form."""
    from glsim.io import truth as T
    from glsim.scene import MeshFile
    from glsim.workflows.sequence import write_sequence

    nodes, at = lattice(4, 3)
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(nodes, [("quad8", q8_cells(4, 3, at))], point_data={"u": step1(nodes)}))
    sc = Scene(cameras=(CAM,), specimen=Specimen(mesh=MeshFile(path=str(tmp_path / "m.vtu"), point_data=("u",))))
    write_sequence(sc, tmp_path / "r", truth=True, backend="cpu")
    ref = T.load(tmp_path / "r" / "c_0000_truth.npz").maps()
    H, W = ref.mask.shape
    v, u = np.mgrid[0:H, 0:W]
    pts = np.column_stack([u.ravel(), v.ravel()]).astype(float)
    got = T.load(tmp_path / "r" / "c_0001_truth.npz").at(pts)
    valid = got.valid.reshape(H, W)
    np.testing.assert_array_equal(valid, ref.mask)
    np.testing.assert_array_equal(got.element.reshape(H, W)[valid], ref.element[valid])
    np.testing.assert_allclose(got.X_undeformed.reshape(H, W, 3)[valid], ref.X_undeformed[valid], atol=1e-9, rtol=0)
    x, y = (got.X_undeformed[got.valid, k] for k in (0, 1))
    expect = np.column_stack([np.broadcast_to(SHIFT[:2], (len(x), 2)), SHIFT[2] + B * x ** 2 + D * x * y])
    np.testing.assert_allclose(got.displacement[got.valid], expect, atol=1e-9, rtol=0)


@pytest.mark.parametrize("mode", ["exact", "q4", "fast"])
def test_library_truth_of_a_quadratic_mesh(tmp_path, mode):
    """A library of a Q8 VTU with truth: its geometry file holds the patches; each compact
    truth file's maps are the renderer's (element, ξ, η, both positions bit for bit; the
    reference point to 1e-9 px), and ``at()`` at the pixel centres is camera 0's step-0 truth
    with the closed-form displacement of step 1."""
    from glsim.io import truth as T
    from glsim.scene import load_scene

    lib = _q8_library(tmp_path, [0, 1], mode, "noise.sigma = [0.5]")
    (geometry,) = (lib / "geometry").iterdir()
    with np.load(geometry) as z:
        assert z["patches"].shape == (12, 9)
    with Renderer(load_scene(lib / "v0000" / "scene.json")) as r:
        full = {s: r.render("c", s, truth=True).truth for s in (0, 1)}
    files = {s: T.load(_library_truth(lib, s)) for s in (0, 1)}
    for s in (0, 1):
        maps = files[s].maps()
        for name in ("mask", "element", "xi", "eta", "X_undeformed", "X_deformed"):
            np.testing.assert_array_equal(getattr(maps, name), getattr(full[s], name), err_msg=name)
        np.testing.assert_allclose(maps.ref_uv, full[s].ref_uv, atol=1e-9, rtol=0, equal_nan=True)
    H, W = full[0].mask.shape
    v, u = np.mgrid[0:H, 0:W]
    got = files[1].at(np.column_stack([u.ravel(), v.ravel()]).astype(float))
    valid = got.valid.reshape(H, W)
    if mode == "exact":    # the rendered maps are the ray's own material point only in exact mode
        np.testing.assert_array_equal(valid, full[0].mask)
        np.testing.assert_allclose(got.X_undeformed.reshape(H, W, 3)[valid], full[0].X_undeformed[valid], atol=1e-9)
    x, y = (got.X_undeformed[got.valid, k] for k in (0, 1))
    expect = np.column_stack([np.broadcast_to(SHIFT[:2], (len(x), 2)), SHIFT[2] + B * x ** 2 + D * x * y])
    np.testing.assert_allclose(got.displacement[got.valid], expect, atol=1e-9, rtol=0)


def _q8_library(tmp_path, steps: list, mode: str, vary: str):
    """A library (one worker, CPU backend) of a Q8 VTU of the paraboloid seen by CAM at
    ``steps`` in ``mode``, varying ``vary`` (a [vary] line); its directory, every job done."""
    from glsim.workflows.library import load_plan, run

    nodes, at = lattice(4, 3)
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(nodes, [("quad8", q8_cells(4, 3, at))], point_data={"u": step1(nodes)}))
    cam = "\n".join(f"{k} = {getattr(CAM, k)}" for k in ("fx", "fy", "cx", "cy"))
    (tmp_path / "spec.toml").write_text(
        f'seed = 1\nsteps = {steps}\n[scene]\n[[scene.cameras]]\nname = "c"\nsize = {list(CAM.size)}\n{cam}\n'
        f'[scene.specimen.mesh]\npath = "m.vtu"\npoint_data = ["u"]\n[scene.render]\nbackend = "cpu"\n'
        f'mode = "{mode}"\n[vary]\n{vary}\n')
    lib = tmp_path / "lib"
    assert run(load_plan(tmp_path / "spec.toml"), lib, workers=1).failed == []
    return lib


def _library_truth(lib, step: int):
    """The truth file of the library's image c_{step}, as its manifest names it."""
    import csv

    with open(lib / "manifest.csv", newline="") as f:
        row = next(r for r in csv.DictReader(f) if r["step"] == str(step))
    return lib / row["truth_file"]


def test_pieces_come_from_the_scene(tmp_path):
    """``[render] pieces`` (the fast mode's linear pieces per element side): read from a scene
    file, kept in scene.json only when not the default (older scene.json files and library
    fingerprints stay as they were), cut once per renderer (a render call asking for other
    pieces is refused by name), a quadratic library's truth key; the fast mode's error falls as
    the pieces' chord error, 1/n² — from 2 to 8 pieces by 16× (asserted: more than 8×)."""
    from glsim.errors import GlsimError
    from glsim.scene import load_scene
    from glsim.scene.model import Render
    from glsim.workflows.library.keys import truth_keys

    nodes, at = lattice(4, 3)
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(nodes, [("quad8", q8_cells(4, 3, at))], point_data={"u": step1(nodes)}))
    text = (f'[[cameras]]\nname = "c"\nsize = [{CAM.size[0]}, {CAM.size[1]}]\nfx = {CAM.fx}\nfy = {CAM.fy}\n'
            f'cx = {CAM.cx}\ncy = {CAM.cy}\n[specimen.mesh]\npath = "m.vtu"\npoint_data = ["u"]\n[render]\n'
            'mode = "fast"\n')
    (tmp_path / "s.toml").write_text(text + "pieces = 8\n")
    sc = load_scene(tmp_path / "s.toml")
    assert sc.render.pieces == 8 and sc.to_dict()["render"]["pieces"] == 8
    assert "pieces" not in sc.replace(render={"pieces": 4}).to_dict()["render"]
    (tmp_path / "scene.json").write_text(sc.to_json())
    assert load_scene(tmp_path / "scene.json") == sc
    errors, (_, _, _, Xd) = {}, closed_form()
    for n in (2, 8):
        with Renderer(sc.replace(render={"pieces": n}), "cpu") as r:
            assert r.pieces.n == n
            t = r.render(0, 1, truth=True).truth
            errors[n] = np.abs(t.X_deformed[t.mask] - Xd[t.mask]).max()
    assert errors[2] > 8 * errors[8] > 0, errors
    with Renderer(sc, "cpu") as r, pytest.raises(GlsimError, match=r"render\.pieces: 2 differs from the renderer's 8"):
        r.render(0, 1, pieces=2)
    for bad in (0, 17, 2.5, True):
        with pytest.raises(GlsimError, match=r"render\.pieces: must be an integer in 1…16"):
            Render(pieces=bad)
    mesh = surface_mesh("quad8")
    keys = [truth_keys(sc.replace(render={"pieces": n}), mesh, ["c"], [1], "float64") for n in (4, 8)]
    assert keys[0] != keys[1]


def test_a_library_varying_pieces_renders_each_with_its_own(tmp_path):
    """A library whose variants differ only in ``render.pieces`` (fast mode, one worker, which
    reuses its renderer between variants that share mesh and reference): each variant's truth is
    that of a renderer made for its own scene, and the two differ."""
    from glsim.io import truth as T
    from glsim.scene import load_scene

    lib = _q8_library(tmp_path, [1], "fast", "render.pieces = [2, 8]")
    import csv
    with open(lib / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    xi = []
    for row in rows:
        with Renderer(load_scene(lib / row["variant"] / "scene.json")) as r:
            full = r.render("c", 1, truth=True).truth
        maps = T.load(lib / row["truth_file"]).maps()
        np.testing.assert_array_equal(maps.xi, full.xi)
        xi.append(maps.xi)
    assert not np.array_equal(xi[0], xi[1], equal_nan=True)


def test_glsim_compare_on_a_quadratic_render(tmp_path):
    """End to end through the command line: a Q8 VTU rendered (CPU), a DIC-like CSV whose
    subset centres carry the closed-form positions and displacements of step 1 plus a known
    bias; `glsim compare` recovers the bias to 1e-9 mm in every component."""
    import json

    from glsim.cli import main as glsim
    from glsim.scene import MeshFile
    from glsim.workflows.sequence import write_sequence

    nodes, at = lattice(4, 3)
    meshio.write(tmp_path / "m.vtu", meshio.Mesh(nodes, [("quad8", q8_cells(4, 3, at))], point_data={"u": step1(nodes)}))
    sc = Scene(cameras=(CAM,), specimen=Specimen(mesh=MeshFile(path=str(tmp_path / "m.vtu"), point_data=("u",))))
    write_sequence(sc, tmp_path / "r", backend="cpu")
    uv = np.random.default_rng(3).uniform([20, 15], [75, 65], (60, 2))
    x, y, Xu, _ = closed_form(deformed=False, points=uv)
    assert ((np.abs(x) < W0 / 2) & (np.abs(y) < H0 / 2)).all()
    U = np.column_stack([np.broadcast_to(SHIFT[:2], (60, 2)), SHIFT[2] + B * x ** 2 + D * x * y])
    bias = np.array([2e-3, -1e-3, 4e-3])
    rows = ["u,v,X,Y,Z,U,V,W"] + [",".join(repr(float(v)) for v in (*p, *(xu + u + bias), *(u + bias)))
                                  for p, xu, u in zip(uv, Xu, U)]
    (tmp_path / "dic.csv").write_text("\n".join(rows) + "\n")
    assert glsim(["compare", str(tmp_path / "dic.csv"), "--truth", str(tmp_path / "r"), "--step", "1",
                  "-o", str(tmp_path / "cmp")]) == 0
    res = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert res["n_compared"] == 60
    by = {r["dir"]: r for r in res["rows"]}
    for j, names in enumerate((("X", "U"), ("Y", "V"), ("Z", "W"))):
        for name in names:
            assert by[name]["mean_mm"] == pytest.approx(bias[j], abs=1e-9)
            assert by[name]["std_mm"] < 1e-9


def test_coverage_ties_are_not_claimed_for_curved_elements():
    """oracle_maps.renderer_ties draws element edges straight between corners: a quadratic mesh's
    are curved in space, so it refuses one instead of giving a wrong tie set."""
    with Renderer(scene(), "cpu", mesh=surface_mesh("quad8")) as c:
        with pytest.raises(ValueError, match="quadratic mesh"):
            oracle_maps.renderer_ties(c, "exact", 0, 0)
