"""Hard cases (issue 17), geometry: GL and the CPU oracle against closed forms computed here,
independently of glsim's own geometry code.

- Grazing views of a flat plate up to 89°, and a set-up translated to (5e4, −3e4, 2e5) mm:
  every pixel's truth is the intersection of its ray with the plate's plane.
- Barrel distortion whose valid radius lies inside the image: the radius is undistorted by
  solving the cubic r (1 + k1 r²) = r_d with numpy's ``roots``; nothing beyond it is drawn.
- A plate whose step crosses the camera plane: the rays meet one plane, in front of or behind
  the camera.
- A twisted (non-planar) bilinear patch that many rays pierce twice: the ray/patch quadratic
  is solved here and the nearer root must be the one rendered.
- GL against the oracle on the same scenes, in every mode: masks, element maps and grey levels
  within derived bounds off the coverage ties (glsim.check.closed_forms, glsim.check.oracle_maps).

Each test states what it compares and its tolerance. The closed forms are exact up to float64
rounding, so the truth tolerance is 1e-9 mm wherever the mode is exact
(glsim.check.closed_forms.FLOAT64). GL's fast mode projects its vertices in float32, so its truth
is held per pixel to that projection's bound times the closed form's mm per image pixel
(closed_forms.fast_bound: about 1/cos of the angle at grazing views). A mask is compared exactly with the closed form on pixel centres farther than 1e-6 px
(or 1e-6 of an element) from the outline. GL's fast mode uses its tie distance
(closed_forms.tie_px: the float32 vertex bound plus the rasterizer's snapping, 2^-GL_SUBPIXEL_BITS
px), as in test_hard_coverage.
"""
import warnings

import numpy as np
import pytest
from _shapes import (
    BACKENDS,
    PLATE_CAM,
    X_TOL,
    band_px,
    custom,
    far_plate,
    finite_where_covered,
    grazing_plate,
    grid_mesh,
    outline_distance,
    plane_truth,
    rays,
    render,
    rotation,
    x_err_ok,
)

from glsim.errors import RenderWarning
from glsim.check import closed_forms, oracle_maps
from glsim.render import Renderer
from glsim.scene.camera import Camera, Distortion

MODES = ["exact", "q4", "fast"]


def max_err(a, b, where):
    return float(np.abs(a[where] - b[where]).max())


# --------------------------------------------------------------------------------------------
# Flat plates: grazing views and a set-up far from the origin


def check_plate(res, closed, backend, mode, ctx):
    """Mask against the projected outline (band_px), X_deformed / X_undeformed against the
    ray/plane closed form (x_err_ok; q4 maps in the image plane, so its X is not checked)."""
    Xu, Xd, d = closed
    t = res.truth
    band = band_px(backend, mode, res.camera.fx, ctx)
    assert finite_where_covered(res)
    assert (d > band).sum() > 300
    assert t.mask[d > band].all(), int((~t.mask[d > band]).sum())
    assert not t.mask[d < -band].any(), int(t.mask[d < -band].sum())
    if mode != "q4":
        fx = res.camera.fx
        for X, closed_X in ((t.X_deformed, Xd), (t.X_undeformed, Xu)):
            ok, worst = x_err_ok(backend, mode, fx, np.where(t.mask[..., None], X, np.nan), closed_X)
            assert ok, worst


@pytest.mark.parametrize("angle", [0, 60, 80, 85, 88, 89])
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("backend", BACKENDS)
def test_grazing_plate_truth_is_the_ray_plane_intersection(backend, mode, angle, ctx_for):
    """Grazing views to 89°: mask equals the projected outline, and X (exact, fast) is within
    1e-9 mm of the ray/plane intersection (GL fast: 1e-3 mm). The intersection's condition
    grows as 1/cos(angle) (57 at 89°); measured ≤ 2.3e-13 mm, so float64 holds throughout."""
    scene, mesh, closed = grazing_plate(angle)
    check_plate(render(scene, mesh, backend, ctx_for(backend), mode), closed, backend, mode, ctx_for(backend))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("backend", BACKENDS)
def test_far_from_origin_loses_no_precision(backend, mode, ctx_for):
    """Camera and plate translated by (5e4, −3e4, 2e5) mm: mask and truth as for the same
    set-up at the origin, against the closed form in the camera frame. X within 1e-9 mm
    (35 ulp of the world coordinates; measured 8e-11 mm, the rounding of the stored nodes)."""
    scene, mesh, closed = far_plate()
    check_plate(render(scene, mesh, backend, ctx_for(backend), mode), closed, backend, mode, ctx_for(backend))


def stretched_plate(stretch=1.4, turn=60.0):
    """A tilted 20 × 15 mm plate of 8 × 6 elements whose step 1 is, in its own plane, a 40 %
    stretch along x followed by a 60° rotation and a small translation: the plate stays in
    its plane, so X_deformed is still the ray/plane intersection, and X_undeformed is that
    point mapped back by the inverse affine map. Returns the scene, mesh and closed form."""
    R, t = rotation(25, -30, 10), np.array([0.3, -0.2, 300.0])
    c, s_ = np.cos(np.radians(turn)), np.sin(np.radians(turn))
    A = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]]) @ np.diag([stretch, 1.0, 1.0])
    b = np.array([0.11, -0.07, 0.0])
    nodes, quads = grid_mesh(np.linspace(-10, 10, 9), np.linspace(-7.5, 7.5, 7))
    pose = lambda p: p @ R.T + t  # noqa: E731
    scene, mesh = custom(pose(nodes), quads, PLATE_CAM, steps=(pose(nodes @ A.T + b),))
    W, H = PLATE_CAM.size
    _, Xd = plane_truth(PLATE_CAM, R, t, np.zeros(3), H, W)
    Xu = pose(((Xd - t) @ R - b) @ np.linalg.inv(A).T)
    corners = np.array([[-10, -7.5, 0], [10, -7.5, 0], [10, 7.5, 0], [-10, 7.5, 0]])
    return scene, mesh, (Xu, Xd, outline_distance(pose(corners @ A.T + b), PLATE_CAM))


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("backend", BACKENDS)
def test_stretch_and_rotation_in_plane(backend, mode, ctx_for):
    """40 % stretch with a 60° in-plane rotation of a tilted plate. The map is affine in the
    plate's plane, so the fast mode's triangles are exact too. Mask against the outline, X
    against the closed form, with the tolerances of check_plate."""
    scene, mesh, closed = stretched_plate()
    check_plate(render(scene, mesh, backend, ctx_for(backend), mode), closed, backend, mode, ctx_for(backend))


# --------------------------------------------------------------------------------------------
# Barrel distortion whose valid radius lies inside the image

K1 = -0.35  # r (1 + k1 r²) stops increasing at r = 1/sqrt(−3 k1) = 0.976; r_d there 0.651
BARREL_CAM = Camera(name="c", size=(160, 120), fx=60.0, fy=60.0, cx=79.5, cy=59.5,
                    distortion=Distortion(k1=K1))
BARREL_Z = 100.0


def undistorted_radius(rd, k1):
    """The smallest root r ≥ 0 of r (1 + k1 r²) = r_d below the fold r = 1/sqrt(−3 k1): the
    eigenvalues of each pixel's companion matrix (what numpy's ``roots`` does); NaN where none."""
    r_fold = 1 / np.sqrt(-3 * k1)
    comp = np.zeros(rd.shape + (3, 3))
    comp[..., 0, 1] = -1 / k1           # monic: r³ + 0 r² + r / k1 − r_d / k1
    comp[..., 0, 2] = rd / k1
    comp[..., 1, 0] = comp[..., 2, 1] = 1.0
    r = np.linalg.eigvals(comp)
    ok = (np.abs(r.imag) < 1e-12) & (r.real >= 0) & (r.real <= r_fold)
    return np.where(ok.any(-1), np.where(ok, r.real, np.inf).min(-1), np.nan)


def barrel_scene():
    """A 600 × 450 mm fronto-parallel plate at 100 mm filling the barrel camera's whole view,
    shifted in its plane at step 1. Closed form: (distorted radius of each pixel, the fold's
    distorted radius, X_deformed from the undistorted radius)."""
    nodes, quads = grid_mesh(np.linspace(-300, 300, 13), np.linspace(-225, 225, 10))
    nodes[:, 2] = BARREL_Z
    shift = np.array([0.37, -0.21, 0.0])
    scene, mesh = custom(nodes, quads, BARREL_CAM, steps=(nodes + shift,))
    xd, yd = rays(BARREL_CAM)
    rd = np.hypot(xd, yd)
    r_fold = 1 / np.sqrt(-3 * K1)
    rd_fold = r_fold * (1 + K1 * r_fold ** 2)
    scale = undistorted_radius(rd, K1) / np.where(rd > 0, rd, 1.0)
    Xd = np.stack([xd * scale * BARREL_Z, yd * scale * BARREL_Z, np.full_like(xd, BARREL_Z)], -1)
    return scene, mesh, (rd, rd_fold, Xd, shift)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("backend", BACKENDS)
def test_barrel_distortion_draws_nothing_beyond_the_valid_radius(backend, mode, ctx_for):
    """k1 = −0.35 folds at a distorted radius of 39 px, inside the 160 × 120 image: no pixel
    beyond it is covered and its grey level is the background, in every mode. Exact mode:
    every pixel within 0.98 of that radius is covered and X within 1e-9 mm of the closed form
    (measured 4e-12 mm; the undistortion's condition grows without bound at the fold, hence
    the 0.98). fast and q4 drop the elements the model cannot project (warned)."""
    scene, mesh, (rd, rd_fold, Xd, shift) = barrel_scene()
    assert rd.max() > 2 * rd_fold
    res = render(scene, mesh, backend, ctx_for(backend), mode)
    t = res.truth
    assert finite_where_covered(res)
    assert not t.mask[rd > rd_fold].any(), int(t.mask[rd > rd_fold].sum())
    assert (res.image[rd > rd_fold] == res.options.background).all()
    if mode == "exact":
        inner = rd < 0.98 * rd_fold
        assert t.mask[inner].all(), int((~t.mask[inner]).sum())
        assert max_err(t.X_deformed, Xd, inner) <= X_TOL, max_err(t.X_deformed, Xd, inner)
        assert max_err(t.X_undeformed, Xd - shift, inner) <= X_TOL


# --------------------------------------------------------------------------------------------
# Elements crossing the camera plane

CROSS_CAM = Camera(name="c", size=(96, 72), fx=100.0, fy=100.0, cx=47.3, cy=35.6)


def crossing_scene():
    """An 80 × 16 mm plate of 8 × 4 elements at 300 mm, mapped affinely at step 1 onto the
    plane z = 30 + 3y (x' = x, y' = 3y − 2, z' = 30 + 3y'): rows of elements in front of the
    camera, one row (material y in [−4, 0]) crossing its plane (z from −12 to 24 mm), one
    behind it. Closed form per pixel: the ray's parameter on the plane (t > 0: in front) and
    the material point (x, y) it meets; X_undeformed, X_deformed."""
    nodes, quads = grid_mesh(np.linspace(-40, 40, 9), np.linspace(-8, 8, 5))
    moved = nodes.copy()
    moved[:, 1] = 3 * nodes[:, 1] - 2
    moved[:, 2] = 30 + 3 * moved[:, 1]
    nodes[:, 2] = 300.0
    scene, mesh = custom(nodes, quads, CROSS_CAM, steps=(moved,))
    xn, yn = rays(CROSS_CAM)
    with np.errstate(divide="ignore"):
        t = 30 / (1 - 3 * yn)
    Xd = np.stack([xn * t, yn * t, t], -1)
    mx, my = Xd[..., 0], (Xd[..., 1] + 2) / 3
    Xu = np.stack([mx, my, np.full_like(mx, 300.0)], -1)
    return scene, mesh, (t, mx, my, Xu, Xd)


def px_distance(f):
    """Distance (px) of each pixel centre to the zero line of a smooth per-pixel function f,
    to first order: f / |∇f|, the gradient by central differences over the pixel grid."""
    gy, gx = np.gradient(f)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.abs(f) / np.hypot(gx, gy)


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("backend", BACKENDS)
def test_elements_crossing_the_camera_plane(backend, mode, ctx_for):
    """No NaN or inf; nothing drawn from behind the camera (every covered X_deformed has
    z > 0; the 288 pixels whose ray meets the plane behind the camera stay empty); the mask
    equals the closed form band_px away from the outline: exact mode also shows the crossing
    row's part in front of the camera, fast and q4 drop that row (warned). X within 1e-9 mm of
    the closed form (exact, fast; GL fast its float32 bound, x_err_ok)."""
    scene, mesh, (t_ray, mx, my, Xu, Xd) = crossing_scene()
    res = render(scene, mesh, backend, ctx_for(backend), mode)
    t = res.truth
    assert finite_where_covered(res)
    assert (t_ray < 0).sum() == 288 and not t.mask[t_ray < 0].any()
    assert (t.X_deformed[t.mask][:, 2] > 0).all()
    want = (t_ray > 0) & (np.abs(mx) < 40) & (np.abs(my) < 8)
    lines = [mx - 40, mx + 40, my - 8, my + 8]
    if mode != "exact":
        want &= ~((my > -4) & (my < 0))  # the crossing row, dropped
        lines += [my + 4, my]
    band = band_px(backend, mode, res.camera.fx, ctx_for(backend))
    sure = (t_ray > 0) & np.all([px_distance(f) > band for f in lines], axis=0)
    sure |= t_ray < 0
    assert want[sure & (my > -4) & (my < 0)].any() == (mode == "exact")
    assert np.array_equal(t.mask[sure], want[sure]), int((t.mask[sure] != want[sure]).sum())
    if mode != "q4":
        for X, closed_X in ((t.X_deformed, Xd), (t.X_undeformed, Xu)):
            ok, worst = x_err_ok(backend, mode, res.camera.fx, np.where(t.mask[..., None], X, np.nan), closed_X)
            assert ok, worst


# --------------------------------------------------------------------------------------------
# Twisted patches pierced twice

TWIST_CAM = Camera(name="c", size=(96, 72), fx=400.0, fy=400.0, cx=47.3, cy=35.6)
FLAT = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], float)  # FE order


def twisted_patch():
    """A 20 × 20 mm square with corners 1 and 3 lifted by 13 mm (z = 6.5 (1 − ξη): a saddle),
    seen nearly along its valley so that about 1,000 rays pierce it twice."""
    twist = FLAT + [[0, 0, 0], [0, 0, 13.0], [0, 0, 0], [0, 0, 13.0]]
    return twist @ rotation(-85, 36, -70).T + [0, 0, 64.0]


def twisted_grid(n=4):
    """The saddle of twisted_patch as n × n elements (step 1), flat at 300 mm at step 0."""
    s = np.linspace(-1, 1, n + 1)
    g, quads = grid_mesh(s, s)
    N = 0.25 * np.stack([(1 - g[:, 0]) * (1 - g[:, 1]), (1 + g[:, 0]) * (1 - g[:, 1]),
                         (1 + g[:, 0]) * (1 + g[:, 1]), (1 - g[:, 0]) * (1 + g[:, 1])], -1)
    return custom(N @ (FLAT + [0, 0, 300.0]), quads, TWIST_CAM, steps=(N @ twisted_patch(),))


def ray_patch_roots(P, xn, yn):
    """Both roots of ray t·(xn, yn, 1) = Σ Nᵢ(ξ, η) Pᵢ for a bilinear patch P (4 × 3, FE corner
    order), solved independently of glsim: the two components of the patch point orthogonal to
    the ray, (1, 0, −xn)·X = 0 and (0, 1, −yn)·X = 0, are bilinear in (ξ, η); eliminating ξ
    leaves a quadratic in η. Returns [(t, ξ, η, X), …] for the two roots (NaN if complex)."""
    a = P.sum(0) / 4
    b = (-P[0] + P[1] + P[2] - P[3]) / 4
    c = (-P[0] - P[1] + P[2] + P[3]) / 4
    e = (P[0] - P[1] + P[2] - P[3]) / 4
    proj = lambda v: (v[0] - xn * v[2], v[1] - yn * v[2])  # noqa: E731
    (A1, A2), (B1, B2), (C1, C2), (D1, D2) = proj(a), proj(b), proj(c), proj(e)
    qa = C2 * D1 - D2 * C1
    qb = A2 * D1 + C2 * B1 - B2 * C1 - D2 * A1
    qc = A2 * B1 - B2 * A1
    disc = qb * qb - 4 * qa * qc
    q = -0.5 * (qb + np.copysign(np.sqrt(np.where(disc >= 0, disc, np.nan)), qb))
    d = np.stack([xn, yn, np.ones_like(xn)], -1)
    out = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for eta in (q / qa, qc / q):
            d1, d2 = B1 + D1 * eta, B2 + D2 * eta
            xi = np.where(np.abs(d1) >= np.abs(d2), -(A1 + C1 * eta) / d1, -(A2 + C2 * eta) / d2)
            X = a + b * xi[..., None] + c * eta[..., None] + e * (xi * eta)[..., None]
            out.append(((X * d).sum(-1) / (d * d).sum(-1), xi, eta, X))
    return out


def nearer_root(P, cam):
    """Per pixel: hit (some root in the patch, in front), pierced twice, the nearer root's
    (ξ, η, X), its distance to the patch border in (ξ, η), and the gap to the farther root (mm)."""
    roots = ray_patch_roots(P, *rays(cam))
    ok = [(np.abs(xi) <= 1) & (np.abs(eta) <= 1) & (t > 0) for t, xi, eta, _ in roots]
    first = ok[0] & (~ok[1] | (roots[0][0] <= roots[1][0]))
    pick = lambda k: np.where(first if roots[0][k].ndim == 2 else first[..., None], roots[0][k], roots[1][k])  # noqa: E731
    xi, eta, X = pick(1), pick(2), pick(3)
    gap = np.abs(roots[0][0] - roots[1][0]) * np.linalg.norm(np.stack([*rays(cam), np.ones(cam.size[::-1])], -1), axis=-1)
    return ok[0] | ok[1], ok[0] & ok[1], xi, eta, X, 1 - np.maximum(np.abs(xi), np.abs(eta)), gap


@pytest.mark.parametrize("n", [1, 4])
@pytest.mark.parametrize("backend", BACKENDS)
def test_twisted_patch_pierced_twice_shows_the_nearer_root(backend, n, ctx_for):
    """The saddle as one element (n = 1) or as n × n elements on the same surface (a bilinear
    function is its own bilinear interpolant on any sub-grid), exact mode. Mask equals the
    closed form 1e-6 (in ξ, η) away from the border; X_deformed within 1e-9 mm of the nearer
    root (measured 3.6e-13 mm; the farther root is ≥ 0.2 mm behind on every twice-pierced
    pixel, so a wrong pick cannot pass); for n = 1 also (ξ, η) within 1e-9."""
    scene, mesh = twisted_grid(n)
    hit, twice, xi, eta, X, margin, gap = nearer_root(twisted_patch(), TWIST_CAM)
    assert twice.sum() > 1000 and gap[twice].min() > 0.19
    t = render(scene, mesh, backend, ctx_for(backend), "exact").truth
    sure = margin > 1e-6
    assert np.array_equal(t.mask[sure | ~hit], hit[sure | ~hit])
    assert max_err(t.X_deformed, X, t.mask) <= X_TOL, max_err(t.X_deformed, X, t.mask)
    Xu = np.stack([10 * xi, 10 * eta, np.full_like(xi, 300.0)], -1)  # the flat square at 300 mm
    assert max_err(t.X_undeformed, Xu, t.mask) <= X_TOL, max_err(t.X_undeformed, Xu, t.mask)
    if n == 1:
        assert max_err(t.xi, xi, t.mask) <= X_TOL and max_err(t.eta, eta, t.mask) <= X_TOL


# --------------------------------------------------------------------------------------------
# GL against the oracle on the same scenes

HARD_SCENES = {"grazing-60": lambda: grazing_plate(60)[:2], "grazing-89": lambda: grazing_plate(89)[:2],
               "far": lambda: far_plate()[:2], "stretch": lambda: stretched_plate()[:2], "barrel": lambda: barrel_scene()[:2],
               "crossing": lambda: crossing_scene()[:2], "twisted": twisted_grid}

def ties(scene, mesh, mode, ctx, spp=1):
    """Camera 0's pixels at step 1 where GL may decide a sample the other way than the oracle
    (glsim.check.oracle_maps.renderer_ties: within the mode's tie distance of an element edge
    or the outline — float64 in exact and q4, fast's float32 vertices snapped to
    GL_SUBPIXEL_BITS)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, "gl", ctx=ctx, mesh=mesh) as r:
            return oracle_maps.renderer_ties(r, mode, 0, 1, spp)


def agreement(a, b, mode, fx, tie):
    """GL truth ``a`` against the oracle's ``b`` of the same view: the mask XOR and the
    element-map differences where both cover, outside the tie pixels ``tie`` (:func:`ties`),
    and the pixels (where both cover, and for X with the same element) whose |Δref_uv| or
    |ΔX_deformed| exceeds its bound (glsim.check.closed_forms: float64 in exact and q4, fast's
    float32 bound per pixel), with the largest of each."""
    both = a.mask & b.mask
    same = both & (a.element == b.element)
    d = np.linalg.norm(a.ref_uv - b.ref_uv, axis=-1)
    dX = np.linalg.norm(a.X_deformed - b.X_deformed, axis=-1)
    ref_bound, X_bound = (closed_forms.mapping(mode, fx, f, b.mask) for f in (b.ref_uv, b.X_deformed))
    return dict(covered=int(both.sum()), xor=int(((a.mask ^ b.mask) & ~tie).sum()),
                element=int((both & (a.element != b.element) & ~tie).sum()),
                ref_over=int((d > ref_bound)[both].sum()), ref_max=float(d[both].max()),
                X_over=int((dX > X_bound)[same].sum()), X_max=float(dX[same].max()))


@pytest.mark.gl
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("case", sorted(HARD_SCENES))
def test_gl_agrees_with_the_oracle_on_hard_scenes(case, mode, gl_ctx):
    """GL against the oracle on every hard scene and mode, within the derived bounds: never
    exact equality of floats across drivers; masks and element maps equal but at ties (the
    exact ties are in test_hard_coverage's sweep)."""
    scene, mesh = HARD_SCENES[case]()
    s = agreement(render(scene, mesh, "gl", gl_ctx, mode).truth, render(scene, mesh, "cpu", None, mode).truth,
                  mode, scene.cameras[0].fx, ties(scene, mesh, mode, gl_ctx))
    assert s["covered"] > 500, s
    assert s["xor"] == 0 and s["element"] == 0, s
    assert s["ref_over"] == 0 and s["X_over"] == 0, s


def image(scene, mesh, backend, ctx, **options):
    """One image (no truth); RenderWarnings ignored as in :func:`render`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, backend, ctx=ctx, mesh=mesh) as r:
            return r.render(0, 1, **options)


@pytest.mark.gl
@pytest.mark.parametrize("subsamples", ["mapped", "newton"])
@pytest.mark.parametrize("case", sorted(HARD_SCENES))
def test_gl_subsamples_agree_with_the_oracle_on_hard_scenes(case, subsamples, gl_ctx):
    """Exact mode at 4 samples per pixel, each sub-sample mapped on its ray or placed by Newton
    from the pixel centre (render.subsamples), against the oracle, which maps every sample:
    every pixel within the exact mode's grey bound (closed_forms.grey: the samples' reference points
    1e-9 px apart — Newton's too, see test_render — and the interpolant's largest gradient) but
    where a sub-sample lies at a tie (:func:`ties`: a silhouette sub-sample decided differently
    moves a pixel by up to 255/4)."""
    scene, mesh = HARD_SCENES[case]()
    options = dict(mode="exact", samples_per_pixel=4)
    a = image(scene, mesh, "gl", gl_ctx, subsamples=subsamples, **options)
    b = image(scene, mesh, "cpu", None, **options)
    assert ("subsamples" in a.stages) == (subsamples == "newton")
    with Renderer(scene, "cpu", mesh=mesh) as c:
        bound = oracle_maps.renderer_grey(c, "exact", 0, 1, 4, closed_forms.FLOAT64)
    over = (np.abs(a.image.astype(np.float64) - b.image) > bound) & ~ties(scene, mesh, "exact", gl_ctx, 4)
    assert not over.any(), int(over.sum())


@pytest.mark.gl
@pytest.mark.parametrize("case", sorted(HARD_SCENES))
def test_gl_float32_exact_on_hard_scenes(case, gl_ctx):
    """precision = "fp32" in exact mode against the float64 oracle: the same coverage and
    elements but within each edge's float32 tie distance (exact32.renderer_ties: its edge
    function), and every reference point within its derived bound
    (glsim.check.exact32.renderer_mapping). Float32 keeps this by working relative to each
    element's centre with the per-element records and the rays made in float64 (CAMERA_LOCAL),
    which needs a driver with float64."""
    from glsim.check import exact32

    scene, mesh = HARD_SCENES[case]()
    b = render(scene, mesh, "cpu", None, "exact").truth
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as g:
            if not g.backend.fp64:
                pytest.skip("float32 relative to the element centre needs GL_ARB_gpu_shader_fp64 for its records")
            a = g.render(0, 1, truth=True, mode="exact", precision="fp32").truth
            tie = exact32.renderer_ties(g, 0, 1)
            bound = exact32.renderer_mapping(g, b, 0, 1) + closed_forms.FLOAT64
    s = agreement(a, b, "exact", scene.cameras[0].fx, tie)
    assert s["covered"] > 500 and s["xor"] == 0 and s["element"] == 0, s
    d = np.linalg.norm(a.ref_uv - b.ref_uv, axis=-1)
    assert not (a.mask & b.mask & ~tie & (d > bound)).any(), float(np.nanmax(d / np.where(bound > 0, bound, 1)))
