"""Image Jacobians (issue 32, glsim.imaging.jacobian): the oracle's against central finite
differences of its own float64 renders, supersampled averaging, the refusals by name, GL against
the oracle and the ``glsim jacobian`` round trip."""
import dataclasses
import functools
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.ndimage import minimum_filter

from glsim import cli
from glsim.backends.contract import Request
from glsim.backends.cpu import rasterize
from glsim.effects import motion
from glsim.errors import SceneError
from glsim.io.fe import specimen_mesh
from glsim.render import Renderer
from glsim.scene import load_scene
from glsim.scene.camera import Distortion, rodrigues
from glsim.scene.mesh import with_displacements
from glsim.imaging import interp
from glsim.imaging import jacobian as jac
from glsim.imaging.view import make_view
from _plates import plate_scene

TILT = ((0.96, 0.0, 0.28), (0.0, 1.0, 0.0), (-0.28, 0.0, 0.96))
DELTA = 1e-5   # mm


def _plate(**render):
    """A 64×48 px camera with distortion before a tilted 20×15 mm plate, stretched, sheared and
    bent at step 1 (one non-trivial deformation); the scene and its mesh."""
    scene = plate_scene(size=(64, 48), fx=900.0, distortion=Distortion(k1=-0.2, p1=1e-3), specimen_R=TILT,
                        **{"interpolation": "cubic", **render})
    mesh = specimen_mesh(scene)
    X = mesh.nodes
    c = X.mean(axis=0)
    u = np.column_stack([0.02 * (X[:, 0] - c[0]) + 0.01 * np.sin(X[:, 1]), 1.5e-3 * (X[:, 1] - c[1]) ** 2,
                         0.3 * np.cos(X[:, 0] / 5)])
    return scene, with_displacements(mesh, [u])


def _image64(r: Renderer, deformed: np.ndarray, cam=None):
    """The oracle's float64 image (before its float32 cast) of ``deformed`` nodes seen by ``cam``
    (default: camera 0 at step 1; its samples placed by the fill factor's aperture), and per pixel
    its samples' one element (_one_per_pixel);
    lit as the oracle lights each sample (glsim.backends.cpu._shade, the Effects of ``deformed``)
    when the scene has [lighting]."""
    from glsim.backends.cpu import _shade
    from glsim.effects import prepare

    opts = r.scene.render
    W, H = (cam or r.scene.cameras[0]).size
    s = opts.supersampling
    view = r.view(0, 1, deformed=deformed) if cam is None else \
        make_view(cam, r.reference.camera, r.mesh.nodes, deformed, r.mesh.quads, warn=False)
    raster = rasterize(view, opts.mode, s, np.sqrt(r.scene.sensor.fill_factor) if r.scene.sensor else 1.0)
    hit = raster["element"] >= 0
    grey = np.full(hit.shape, opts.background)
    grey[hit] = r.backend.sampler(opts.interpolation)(raster["ref_uv"][hit])
    if r.scene.lighting is not None:
        fx = prepare(r.scene, deformed, r.mesh.quads, view.camera, 0, 1, np.empty(0))
        grey[hit] = _shade(view, raster, hit, grey[hit], fx)
    return grey.reshape(H, s, W, s).mean(axis=(1, 3)).ravel(), _one_per_pixel(raster, opts.mode, H, W, s)


def _one_per_pixel(raster: dict, mode: str, H: int, W: int, s: int) -> np.ndarray:
    """Per pixel (H·W,) the one element its s × s samples of ``raster`` fall in, −2 where they
    differ, −1 on the background; in mode fast one triangle of it (the grey's derivative jumps
    across the diagonal: ξ − η = 2w₁ ≥ 0 in (0, 1, 2), −2w₂ ≤ 0 in (0, 2, 3))."""
    el = raster["element"]
    if mode == "fast":
        el = np.where(el >= 0, 2 * el + (raster["xi"] < raster["eta"]), el)
    el = el.reshape(H, s, W, s).transpose(0, 2, 1, 3).reshape(H * W, s * s)
    return np.where((el == el[:, :1]).all(axis=1), el[:, 0], -2)


@pytest.mark.parametrize("mode, spp, interpolation, fill", [("exact", 1, "cubic", 1.0), ("q4", 1, "cubic", 1.0),
                                                            ("exact", 4, "cubic", 1.0), ("exact", 1, "procedural", 1.0),
                                                            ("q4", 4, "procedural", 1.0), ("exact", 4, "cubic", 0.5),
                                                            ("q4", 9, "cubic", 0.3), ("fast", 1, "cubic", 1.0),
                                                            ("fast", 4, "bspline3", 1.0)])
def test_oracle_matches_central_differences(mode, spp, interpolation, fill):
    """_against_central_differences of the oracle's float64 renders; procedural: the speckle's
    own dots evaluated exactly, their smooth edges' gradient (glsim.scene.speckle.gradient); a fill
    factor below 1: the samples at c + √fill·((k + ½)/s − ½), rendered as shifted cameras
    (glsim.imaging.jacobian.shifted_cameras; fails with the full pixel's rays, checked); fast: the
    perspective-correct triangles' weights moved by their corners' projections and depths
    (glsim.imaging.jacobian.fast_sensitivities; fails without the depths' term, checked)."""
    scene, mesh = _plate(backend="cpu", mode=mode, samples_per_pixel=spp, interpolation=interpolation)
    scene = scene.replace(sensor={"fill_factor": fill}) if fill < 1 else scene
    with Renderer(scene, mesh=mesh) as r:
        J = r.render(0, 1, jacobian=True).jacobian.tocsc()
        assert J.shape == (64 * 48, 3 * mesh.n_nodes)
        _against_central_differences(J, mesh, lambda nodes: _image64(r, nodes), seed=1)


def _against_central_differences(J, mesh, image, seed: int) -> None:
    """J's columns of 5 random nodes (``seed``) against central differences of ``image(nodes)``
    (the float64 image (W·H,) and per pixel its samples' one element, −2 where they differ) about
    step 1: per pixel whose samples stay in one element in both renders, |FD − J| ≤ 1e-4 of the
    entry (entries below 1e-3 of the column's largest count at that floor: FD's own rounding);
    background pixels have no derivative; over 100 entries checked."""
    deformed, checked = mesh.deformed(1), 0
    for node in np.random.default_rng(seed).choice(mesh.n_nodes, 5, replace=False):
        for c in range(3):
            (plus, ep), (minus, em) = (image(deformed + sign * DELTA * (np.arange(3) == c)
                                             * (np.arange(mesh.n_nodes) == node)[:, None]) for sign in (1, -1))
            fd = (plus - minus) / (2 * DELTA)
            col = J[:, 3 * node + c].toarray().ravel()
            same = (ep == em) & (ep >= -1)
            floor = 1e-3 * np.abs(col).max()
            assert np.all(np.abs(fd - col)[same] <= 1e-4 * np.maximum(np.abs(col[same]), floor))
            assert not np.any(col[ep == -1]), "background pixels have no derivative"
            checked += np.count_nonzero(col[same])
    assert checked > 100


def _curved(**render):
    """The Q8 and T6 meshes of tests/test_quadratic.py's paraboloid (before its camera, with
    distortion), displaced at step 1 by a field that is not in the patches' space (so the
    patches bend): the scene and the meshes."""
    from test_quadratic import CAM, scene as qscene, surface_mesh

    cam = dataclasses.replace(CAM, size=(48, 40), cx=23.3, cy=19.6, fx=600.0, fy=600.0,
                              distortion=Distortion(k1=-0.2, p1=1e-3))
    scene = qscene().replace(cameras=(cam,), render={"backend": "cpu", "interpolation": "cubic", **render})
    meshes = []
    for kind in ("quad8", "triangle6"):
        m = surface_mesh(kind)
        X = m.nodes
        u = np.column_stack([0.02 * X[:, 0] + 0.01 * np.sin(X[:, 1]), 1.5e-3 * X[:, 1] ** 2, 0.3 * np.cos(X[:, 0] / 5)])
        meshes.append(with_displacements(m, [u]))
    return scene, meshes


def _curved_image(r: Renderer, cam, mesh, deformed, mode: str):
    """The oracle's float64 image of quadratic ``mesh``'s ``deformed`` nodes seen by ``cam``
    with ``r``'s reference and samples per pixel (glsim.backends.cpu.rasterize_quadratic), lit
    when the scene is, and per pixel its samples' one element (−2 where they differ)."""
    from glsim.backends.cpu import _shade, rasterize_quadratic
    from glsim.effects import prepare
    from glsim.imaging.quadview import make_quad_view

    s, (W, H) = r.scene.render.supersampling, cam.size
    lit = r.scene.lighting is not None
    pieces_def = r.pieces.mesh.at_grid(deformed) if lit else None
    if mode == "fast":   # the pieces drawn as linear quads, their nodes at the patches' grid
        pm = r.pieces.mesh
        view = make_view(cam, r.reference.camera, pm.nodes, pm.nodes + pm.at_grid(deformed - mesh.nodes), pm.quads,
                         warn=False)
        raster = rasterize(view, mode, s)
    else:
        view = make_quad_view(cam, r.reference.camera, mesh.nodes, deformed, mesh.patches, warn=False, mode=mode,
                              pieces=r.pieces if lit else None, pieces_def=pieces_def)
        raster = rasterize_quadratic(view, mode, s)
    hit = raster["element"] >= 0
    grey = np.full(hit.shape, r.scene.render.background)
    grey[hit] = r.backend.sampler(r.scene.render.interpolation)(raster["ref_uv"][hit])
    if lit:   # the normals interpolated over the pieces, in their state (as the oracle renders)
        grey[hit] = _shade(view, raster, hit, grey[hit], prepare(r.scene, pieces_def, r.pieces.mesh.quads, cam, 0, 1,
                                                                np.empty(0)))
    return grey.reshape(H, s, W, s).mean(axis=(1, 3)).ravel(), _one_per_pixel(raster, mode, H, W, s)


@pytest.mark.parametrize("mode, spp, lit", [("exact", 1, False), ("q4", 1, False),
                                           pytest.param("exact", 4, False, marks=pytest.mark.slow),   # the oracle's 4-spp re-renders
                                           pytest.param("exact", 1, True, marks=pytest.mark.slow),
                                           pytest.param("q4", 1, True, marks=pytest.mark.slow), ("fast", 4, False), ("fast", 1, True)])
def test_quadratic_jacobian_matches_central_differences(mode, spp, lit):
    """Q8 and T6 (derived centres: their derivatives spread over the nodes) and a mid-side node
    among those checked: as test_oracle_matches_central_differences, the oracle's curved raster
    (glsim.backends.cpu.rasterize_quadratic) re-rendered with one node moved ±DELTA; ``lit``:
    with LIGHTING (smooth normals of the pieces, 3 per side, multiplicative; flat in q4), which
    fails without the pieces' normals chained to the nodes (checked); fast: the pieces drawn as
    linear quads, their Jacobian chained to the nodes by PiecesMesh.grid_matrix."""
    scene, meshes = _curved(mode=mode, samples_per_pixel=spp, pieces=3)
    if lit:
        scene = scene.replace(lighting={**LIGHTING, "combine": "multiplicative",
                                        "normals": "flat" if mode == "q4" else "smooth"})
    for mesh in meshes:
        with Renderer(scene, mesh=mesh) as r:
            res = r.render(0, 1, jacobian=True)
            J = res.jacobian.tocsc()
            image = functools.partial(_curved_image, r, scene.cameras[0], mesh, mode=mode)
            assert np.abs(image(deformed=mesh.deformed(1))[0] - res.image.ravel()).max() <= 1e-6

            deformed = mesh.deformed(1)
            used = np.unique(mesh.patches[:, :8])
            mid = np.setdiff1d(used, mesh.patches[:, :4])               # mid-side nodes
            picks = [mid[len(mid) // 2], *np.random.default_rng(2).choice(used, 3, replace=False)]
            checked = 0
            for node in picks:
                for c in range(3):
                    step = DELTA * (np.arange(3) == c) * (np.arange(mesh.n_nodes) == node)[:, None]
                    (plus, ep), (minus, em) = image(deformed=deformed + step), image(deformed=deformed - step)
                    fd = (plus - minus) / (2 * DELTA)
                    col = J[:, 3 * node + c].toarray().ravel()
                    same = (ep == em) & (ep >= -1)
                    floor = 1e-3 * max(np.abs(col).max(), 1e-300)
                    assert np.all(np.abs(fd - col)[same] <= 1e-4 * np.maximum(np.abs(col[same]), floor)), (node, c)
                    assert not np.any(col[ep == -1]), "background pixels have no derivative"
                    checked += np.count_nonzero(col[same])
            assert checked > 100, checked


# k3, k6 (r⁶ at r ≲ 0.04: columns ~1e-7 grey per unit): the raster's rounding, ~1e-14 grey, over 2δ stays
# below the criterion's 1e-4 · 1e-3 of the column only for δ ≈ 10 (the differences shrink as 1/δ; at
# δ = 10 they are ~1e-15, no truncation seen); skew (~1e-5 grey per px here): the lit raster's rounding
# (~4e-14) over 2δ at δ = 1e-5 is 1e-4 of its smallest counted entries, at δ = 1e-4 a tenth of that
RIG_STEPS = {"rx": 1e-7, "ry": 1e-7, "rz": 1e-7, "p1": 1e-6, "p2": 1e-6, "s1": 1e-6, "skew": 1e-4,
             "s3": 1e-6, "k2": 1e-2, "k5": 1e-2, "s2": 1e-2, "s4": 1e-2, "k3": 10.0, "k6": 10.0}   # else 1e-5


def _moved(cam, name: str, d: float):
    """``cam`` with parameter ``name`` of jacobian.RIG_COLUMNS changed by d (rotation: exp([d·e])·R)."""
    col = jac.RIG_COLUMNS.index(name)
    if col < 3:
        return dataclasses.replace(cam, R=rodrigues(d * np.eye(3)[col]) @ cam.rotation)
    if col < 6:
        return dataclasses.replace(cam, t=np.array(cam.t) + d * np.eye(3)[col - 3])
    if col < 11:
        return dataclasses.replace(cam, **{name: getattr(cam, name) + d})
    return dataclasses.replace(cam, distortion=Distortion.from_opencv(cam.distortion.coeffs + d * np.eye(12)[col - 11]))


@pytest.mark.parametrize("mode, spp, extra", [("exact", 1, None), ("q4", 4, None), ("exact", 1, "lit"),
                                              ("exact", 1, "vignetted"), ("fast", 4, None), ("fast", 1, "lit")])
def test_rig_jacobian_matches_central_differences(mode, spp, extra):
    """Every camera parameter (pose, intrinsics, the 12 distortion coefficients) of a posed, skewed
    camera; bspline3 (C², so no kink of the kernel's second derivative in the differences); lit:
    with LIGHTING (the lights stay in the world as the pose changes; smooth normals, multiplicative),
    which the pose columns fail without the lighting's pose terms (checked); vignetted: the image
    times the re-posed camera's own flat field (its gain moves with the intrinsics and distortion:
    fails without that term, checked)."""
    from glsim.effects.vignetting import flat_field

    scene, mesh = _plate(backend="cpu", mode=mode, samples_per_pixel=spp, interpolation="bspline3")
    cam = dataclasses.replace(scene.cameras[0], skew=0.7, R=rodrigues(np.array([0.02, -0.03, 0.01])), t=(1.0, -0.5, 3.0),
                              distortion=Distortion(k1=-0.2, p1=1e-3, k4=0.05, s1=0.01))
    scene = scene.replace(cameras=(cam,), **({"lighting": {**LIGHTING, "combine": "multiplicative"}} if extra == "lit"
                                             else {"vignetting": CAMERA_EFFECTS["vignetting"]} if extra else {}))

    def image(c):
        grey, one = _image64(r, mesh.deformed(1), c)
        return (grey * flat_field(c, r.scene.vignetting).ravel() if r.scene.vignetting else grey), one

    with Renderer(scene, mesh=mesh) as r:
        res = r.render(0, 1, rig=True)
        assert res.jacobian.shape == (64 * 48, 3 * mesh.n_nodes) and res.rig_jacobian.shape == (64 * 48, 23)
        J = res.rig_jacobian.toarray()
        for col, name in enumerate(jac.RIG_COLUMNS):
            d = RIG_STEPS.get(name, 1e-5)
            (plus, ep), (minus, em) = (image(_moved(cam, name, sign * d)) for sign in (1, -1))
            same = (ep == em) & (ep >= -1)
            fd = (plus - minus)[same] / (2 * d)
            floor = 1e-3 * np.abs(J[:, col]).max()
            assert floor > 0 and np.all(np.abs(fd - J[same, col]) <= 1e-4 * np.maximum(np.abs(J[same, col]), floor)), name


def test_interpolant_gradient_is_the_derivative_of_sample():
    img = np.random.default_rng(0).random((30, 40))
    uv = np.random.default_rng(1).random((200, 2)) * [34, 24] + 2.0
    h = 1e-6
    for method in interp.METHODS:
        c = interp.prepare(img, method, np.float64)
        fd = np.stack([(interp.sample(c, uv + d, method) - interp.sample(c, uv - d, method)) / (2 * h)
                       for d in ([h, 0.0], [0.0, h])], axis=-1)
        np.testing.assert_allclose(interp.gradient(c, uv, method), fd, atol=2e-8)


def test_supersampled_pixels_average_their_samples():
    """spp = 4: the pixel's row is the mean of its 2×2 samples' rows, which are the pixels of the
    sample camera (size ×2) rendered at one sample per pixel."""
    scene, mesh = _plate(backend="cpu", samples_per_pixel=4)
    with Renderer(scene, mesh=mesh) as r:
        J = r.render(0, 1, jacobian=True).jacobian
        fine = r.render(0, 1, jacobian=True, samples_per_pixel=1)
        reference = r.reference
    scam = jac.sample_camera(scene.cameras[0], 2)
    assert scam.size == (128, 96)
    scene2 = scene.replace(cameras=(scam,), render={"samples_per_pixel": 1})
    with Renderer(scene2, mesh=mesh, reference=reference) as r2:   # (the same speckle)
        Jf = r2.render(0, 1, jacobian=True).jacobian
    W, H = 64, 48
    rows = np.arange(4 * W * H)
    u, v = rows % (2 * W), rows // (2 * W)
    pool = sp.coo_matrix((np.full(len(rows), 0.25), ((v // 2) * W + u // 2, rows)), shape=(W * H, 4 * W * H))
    assert abs(pool @ Jf - J).max() <= 1e-12 * abs(J).max()
    assert abs(fine.jacobian - J).max() > 1e-3 * abs(J).max()   # (not the pixel centres' Jacobian)


OPTICS = {"focal_length": 50.0, "f_number": 2.8, "focus_distance": 300.0, "pixel_pitch": 0.005}


# the tilted, bent plate at ~300 mm focused at 250 mm: σ ≈ 1–1.6 px (windows of 7–11 px), varying over it
DOF = {"focal_length": 25.0, "f_number": 16.0, "focus_distance": 250.0, "pixel_pitch": 0.01}


def _blurred64(r: Renderer, deformed: np.ndarray, cam=None):
    """The depth of field's model image in float64 (W·H,): _image64 (of ``cam``, default camera
    0) blurred by the oracle's gather with each pixel's σ (or radius) from its covered samples'
    mean depth in float64 (the renderer rounds it to float32), per pixel one element (−2 where
    its samples differ), the blur's window radius per pixel, and a bound of the relative change
    of σ that rounding makes, twice ulp(Z)/2 · max|∂σ/∂Z| / min σ (~1e-6 here): the Jacobian is
    made at the rendered σ map, so entries may differ from the float64 model's by that share of
    the largest."""
    from glsim.effects import dof

    opts, optics = r.scene.render, r.scene.optics
    W, H = r.scene.cameras[0].size
    s = opts.supersampling
    grey, one = _image64(r, deformed, cam)
    view = r.view(0, 1, deformed=deformed) if cam is None else \
        make_view(cam, r.reference.camera, r.mesh.nodes, deformed, r.mesh.quads, warn=False)
    raster = rasterize(view, opts.mode, s)
    z = np.where(raster["element"] >= 0, raster["depth"], 0.0).reshape(H, s, W, s)
    n = (z > 0).sum(axis=(1, 3))
    depth = np.divide(z.sum(axis=(1, 3)), n, out=np.zeros((H, W)), where=n > 0)
    size = dof.blur_sigma(depth, optics)
    blur = dof.blur_exact if optics.kernel == "gaussian" else dof.blur_disk
    rounding = 2 * np.spacing(np.float32(depth.max())) / 2 * np.abs(dof.size_derivative(depth, optics)).max() \
        / size[size > 0].min()
    return blur(grey.reshape(H, W), size).ravel(), one, dof.kernel_radius(size, optics.kernel), float(rounding)


@pytest.mark.parametrize("mode, spp, kernel, lit", [("exact", 1, "gaussian", False), ("q4", 1, "disk", False),
                                                     ("exact", 4, "gaussian", True)])
def test_depth_of_field_jacobian_matches_central_differences(mode, spp, kernel, lit):
    """Through the depth of field's blur (glsim.effects.dof.through_blur): the blurred pixel moves
    with its neighbours' grey (C·J) and with its own blur size through its depth (∂out/∂σ ·
    ∂σ/∂Z · ∂Z/∂u). Against central differences of the oracle's blurred model image in float64
    (_blurred64, checked to be the rendered image to the σ rounding's effect) on every pixel whose
    window holds only pixels of one element in both renders and whose window radius stays the
    same (_blurred_entries_agree). Leaving out the depth's part fails it (checked). (Mode fast:
    its triangles' diagonals leave no blur window of one triangle here; its depth's derivative
    is checked below, the blur's chain is the same.)"""
    scene, mesh = _plate(backend="cpu", mode=mode, samples_per_pixel=spp)
    scene = scene.replace(optics={**DOF, "kernel": kernel}, **({"lighting": LIGHTING} if lit else {}))
    with Renderer(scene, mesh=mesh) as r:
        res = r.render(0, 1, jacobian=True)
        J = res.jacobian.tocsc()
        deformed = mesh.deformed(1)
        model, _, R0, rounding = _blurred64(r, deformed)
        assert np.abs(model - res.image.ravel()).max() <= 1e-5
        win = 2 * int(R0.max()) + 1
        checked = 0
        for node in np.random.default_rng(7).choice(mesh.n_nodes, 5, replace=False):
            for c in range(3):
                step = DELTA * (np.arange(3) == c) * (np.arange(mesh.n_nodes) == node)[:, None]
                (plus, ep, Rp, _), (minus, em, Rm, _) = _blurred64(r, deformed + step), _blurred64(r, deformed - step)
                col = J[:, 3 * node + c].toarray().ravel()
                checked += _blurred_entries_agree((plus - minus) / (2 * DELTA), col, ep, em, Rp, Rm, R0, win, rounding)
        assert checked > 100


def test_fast_depth_derivative_matches_central_differences():
    """Mode fast's depth (the oracle's 1/Σ λ_j/z_j per sample, what its depth of field blurs with):
    image_jacobian(depth=True)'s per-pixel mean over the covered samples against central
    differences of the oracle's raster depths, _against_central_differences' criterion on the
    pixels whose samples stay in one triangle; fails without the corners' own depth term (checked)."""
    scene, mesh = _plate(backend="cpu", mode="fast", samples_per_pixel=4)
    cam, s = scene.cameras[0], 4
    W, H = cam.size

    def depth(deformed):
        with Renderer(scene, mesh=mesh) as r:
            raster = rasterize(make_view(cam, r.reference.camera, mesh.nodes, deformed, mesh.quads, warn=False), "fast", s)
        z = np.where(raster["element"] >= 0, raster["depth"], 0.0).reshape(H, s, W, s)
        n = (z > 0).sum(axis=(1, 3))
        return (np.divide(z.sum(axis=(1, 3)), n, out=np.zeros((H, W)), where=n > 0).ravel(),
                _one_per_pixel(raster, "fast", H, W, s), raster)

    with Renderer(scene, mesh=mesh) as r:
        coeffs = interp.prepare(r.reference.image, "cubic", np.float64)
        grad = functools.partial(interp.gradient, coeffs, method="cubic")
        raster = depth(mesh.deformed(1))[2]
        _, _, (z, J_z, _) = jac.image_jacobian(cam, r.reference.camera,
                                               jac.MeshState(mesh.nodes, mesh.deformed(1), mesh.quads), raster, grad,
                                               jac.JacobianOptions(mode="fast", samples=s, depth=True))
    hit = raster["element"] >= 0
    assert np.abs(z[hit] - raster["depth"][hit]).max() <= 1e-12 * z.max()
    _against_central_differences(J_z.tocsc(), mesh, lambda nodes: depth(nodes)[:2], seed=3)


def test_rig_jacobian_through_the_depth_of_field_matches_central_differences():
    """The rig Jacobian through the blur: a pose change moves the depths and so σ (J_z's rig
    columns), the intrinsics and distortion move (ξ, η) and with it the depth. Every camera
    parameter of the posed, skewed camera of test_rig_jacobian_matches_central_differences,
    against central differences of _blurred64 of re-posed / re-calibrated cameras
    (_blurred_entries_agree).
    Leaving out the depth's rig columns fails the pose's (checked)."""
    scene, mesh = _plate(backend="cpu", mode="exact", interpolation="bspline3")
    cam = dataclasses.replace(scene.cameras[0], skew=0.7, R=rodrigues(np.array([0.02, -0.03, 0.01])), t=(1.0, -0.5, 3.0),
                              distortion=Distortion(k1=-0.2, p1=1e-3, k4=0.05, s1=0.01))
    with Renderer(scene.replace(cameras=(cam,), optics=DOF), mesh=mesh) as r:
        J = r.render(0, 1, rig=True).rig_jacobian.toarray()
        _, _, R0, rounding = _blurred64(r, mesh.deformed(1), cam)
        win = 2 * int(R0.max()) + 1
        for col, name in enumerate(jac.RIG_COLUMNS):
            d = RIG_STEPS.get(name, 1e-5)
            (plus, ep, Rp, _), (minus, em, Rm, _) = (_blurred64(r, mesh.deformed(1), _moved(cam, name, sign * d))
                                                     for sign in (1, -1))
            assert _blurred_entries_agree((plus - minus) / (2 * d), J[:, col], ep, em, Rp, Rm, R0, win, rounding), name


def _blurred_entries_agree(fd, col, ep, em, Rp, Rm, R0, win: int, rounding: float) -> int:
    """_against_central_differences' criterion for a blurred column ``col`` (W·H,) and its
    central differences ``fd``, on the pixels whose window (``win`` px) holds one element in both
    renders (``ep``, ``em``) and whose radius stays R0, plus ``rounding`` of the column's largest
    entry (_blurred64); asserts, and returns the entries checked (non-zero)."""
    clean = minimum_filter(((ep == em) & (ep >= -1)).reshape(48, 64), size=win, mode="nearest").ravel()
    clean &= ((Rp == R0) & (Rm == R0)).ravel()
    scale = np.abs(col).max()
    assert scale > 0 and np.all(np.abs(fd - col)[clean] <= 1e-4 * np.maximum(np.abs(col[clean]), 1e-3 * scale)
                                + rounding * scale)
    return int(np.count_nonzero(col[clean]))


# a point light with attenuation and a highlight on the plate, and a spotlight whose smooth edge
# (cutoff 6°, edge 3°, ~100 mm away: radii 5–10 mm) crosses it
LIGHTING = {"ambient": -0.02, "diffuse": 0.6, "specular": 0.4, "shininess": 6.0,
            "lights": [{"position": [12.0, -8.0, 150.0], "intensity": 0.5, "attenuation": 2e-5},
                       {"position": [-30.0, 20.0, 200.0], "direction": [30.0, -20.0, 100.0], "cutoff": 6.0,
                        "edge": 3.0, "intensity": 0.4}]}


@pytest.mark.parametrize("mode, spp, normals, combine", [("exact", 1, "smooth", "additive"),
                                                          ("q4", 1, "flat", "multiplicative"),
                                                          ("exact", 4, "smooth", "multiplicative"),
                                                          ("fast", 4, "smooth", "multiplicative"),
                                                          ("fast", 1, "flat", "additive")])
def test_lit_jacobian_matches_central_differences(mode, spp, normals, combine):
    """Phong lighting (docs/jacobian.md, "With lighting"): the lit grey moves with the sample's
    point, its interpolated normal and, through the corner normals, with the nodes of the
    elements around it (smooth normals: a node's 1-ring). Against central differences of the
    oracle's lit float64 render (_image64) (checked to be the rendered image), the nodes moved including
    ones whose only effect on some pixels is through the normals (_against_central_differences). Leaving out the normals' derivative fails it (checked)."""
    scene, mesh = _plate(backend="cpu", mode=mode, samples_per_pixel=spp)
    scene = scene.replace(lighting={**LIGHTING, "normals": normals, "combine": combine})
    with Renderer(scene, mesh=mesh) as r:
        res = r.render(0, 1, jacobian=True)
        assert np.abs(_image64(r, mesh.deformed(1))[0] - res.image.ravel()).max() <= 1e-6
        _against_central_differences(res.jacobian.tocsc(), mesh, lambda nodes: _image64(r, nodes), seed=5)


CAMERA_EFFECTS = {"vignetting": {"natural": True, "radial": [0.3, -0.1]}, "psf": {"kind": "gaussian", "sigma": 0.9},
                  "sensor": {"prnu": 1.5, "dsnu": 2.0}}


def _with_camera_effects(scene, grey64: np.ndarray) -> np.ndarray:
    """The oracle's camera-effect stages in float64, in the pipeline's order, on a raster's grey
    (W·H,): vignetting's gain, the PSF (scipy.ndimage), fixed-pattern noise (glsim.effects)."""
    from glsim.effects import noise, psf
    from glsim.effects.vignetting import flat_field

    cam = scene.cameras[0]
    image = grey64.reshape(cam.height, cam.width) * flat_field(cam, scene.vignetting)
    image = psf.apply(image, psf.make_kernel(scene.psf))
    return noise.fixed_pattern(image, scene.sensor.prnu, scene.sensor.dsnu, cam.bit_depth,
                               noise.fixed_pattern_seed(scene.seed, 0)).ravel()


def test_camera_effects_jacobian_matches_central_differences():
    """Vignetting, a Gaussian PSF and fixed-pattern noise act on the image linearly, so its
    Jacobian is the raster's through them (glsim.compose.chain.through_camera_effects): against
    central differences of the float64 raster put through the oracle's own effect stages (the
    rendered image's composition, checked), on every pixel whose PSF window (±4 px) holds only
    pixels whose samples stay in one element in both renders; test_oracle_matches_central_differences's
    criterion."""
    scene, mesh = _plate(backend="cpu", mode="exact")
    scene = scene.replace(**CAMERA_EFFECTS)
    R = 4                                     # ceil(4σ): the Gaussian kernel's half-width
    with Renderer(scene, mesh=mesh) as r:
        res = r.render(0, 1, jacobian=True)
        J = res.jacobian.tocsc()
        deformed = mesh.deformed(1)
        grey, _ = _image64(r, deformed)
        assert np.abs(_with_camera_effects(scene, grey) - res.image.ravel()).max() <= 1e-6
        checked = 0
        for node in np.random.default_rng(3).choice(mesh.n_nodes, 5, replace=False):
            for c in range(3):
                (plus, ep), (minus, em) = (_image64(r, deformed + sign * DELTA * (np.arange(3) == c)
                                                    * (np.arange(mesh.n_nodes) == node)[:, None]) for sign in (1, -1))
                fd = (_with_camera_effects(scene, plus) - _with_camera_effects(scene, minus)) / (2 * DELTA)
                col = J[:, 3 * node + c].toarray().ravel()
                clean = minimum_filter(((ep == em) & (ep >= -1)).reshape(48, 64), size=2 * R + 1, mode="nearest").ravel()
                floor = 1e-3 * np.abs(col).max()
                assert np.all(np.abs(fd - col)[clean] <= 1e-4 * np.maximum(np.abs(col[clean]), floor))
                checked += np.count_nonzero(col[clean])
        assert checked > 100


def _over_exposure(tl, taus, points, image):
    """The mean of ``image(nodes)`` (a float64 image (W·H,) and per pixel its samples' one
    element, −2 where they differ) over the sub-frames' states ``tl.at(τ_i, points)``
    (``points(k)``: the nodes at load step k), and per pixel one element (−2 where a sub-frame's
    samples or two sub-frames differ)."""
    grey, one = 0.0, None
    for tau in taus:
        g, e = image(tl.at(tau, points))
        grey, one = grey + g / len(taus), e if one is None else np.where(one == e, e, -2)
    return grey, one


EXPOSURES = {"rigid": {"time": 0.01, "samples": 3, "velocity": [40.0, -20.0, 10.0],
                       "angular_velocity": [0.3, -0.2, 1.0], "centre": [1.0, -2.0, 600.0]},
             "between steps": {"time": 0.8, "samples": 3, "step_time": 1.0}}


@pytest.mark.parametrize("kind", sorted(EXPOSURES))
def test_exposure_jacobian_matches_central_differences(kind):
    """[exposure]: the image is the mean of sub-frames at states X(τ_i) (a rigid motion about a
    given centre, or the interpolation between load steps 0–1–2 around step 1), so its Jacobian
    is the mean of theirs, each chained by ∂X(τ)/∂X_1 (Timeline.derivative: R(ωτ), or step 1's
    weight): against central differences of the float64 sub-frames' mean with step 1's node
    moved ±δ, test_oracle_matches_central_differences's criterion (every sub-frame's samples in
    one element in both renders); the rig Jacobian's pose and focal columns likewise."""
    scene, mesh = _plate(backend="cpu", mode="exact")
    u1 = mesh.displacements[1]
    mesh = with_displacements(dataclasses.replace(mesh, displacements=(mesh.displacements[0],)),
                              [u1, 1.6 * u1 + np.array([0.05, 0.0, 0.1])])
    scene = scene.replace(exposure=EXPOSURES[kind])
    with Renderer(scene, mesh=mesh) as r:
        res = r.render(0, 1, rig=True)
        J, J_rig = res.jacobian.tocsc(), res.rig_jacobian.toarray()
        tl = motion.timeline(scene.exposure, mesh, 1)
        taus = motion.sample_offsets(scene.exposure.time, scene.exposure.samples)
        grey, _ = _over_exposure(tl, taus, mesh.deformed, functools.partial(_image64, r))
        np.testing.assert_allclose(grey, res.image.ravel(), rtol=0, atol=1e-6)   # the rendered image's mean
        checked = 0
        for node in np.random.default_rng(5).choice(mesh.n_nodes, 4, replace=False):
            for c in range(3):
                def moved(sign):
                    step = sign * DELTA * (np.arange(3) == c) * (np.arange(mesh.n_nodes) == node)[:, None]
                    return _over_exposure(tl, taus, lambda k: mesh.deformed(k) + (step if k == 1 else 0),
                                          functools.partial(_image64, r))
                (plus, ep), (minus, em) = moved(1), moved(-1)
                col = J[:, 3 * node + c].toarray().ravel()
                same = (ep == em) & (ep >= -1)
                floor = 1e-3 * np.abs(col).max()
                assert np.all(np.abs((plus - minus) / (2 * DELTA) - col)[same]
                              <= 1e-4 * np.maximum(np.abs(col[same]), floor))
                checked += np.count_nonzero(col[same])
        assert checked > 100
        for name in ("rz", "tx", "fx"):
            d = RIG_STEPS.get(name, 1e-5)
            (plus, ep), (minus, em) = (_over_exposure(tl, taus, mesh.deformed, functools.partial(
                _image64, r, cam=_moved(scene.cameras[0], name, v))) for v in (d, -d))
            same, col = (ep == em) & (ep >= -1), J_rig[:, jac.RIG_COLUMNS.index(name)]
            floor = 1e-3 * np.abs(col).max()
            assert np.all(np.abs((plus - minus)[same] / (2 * d) - col[same]) <= 1e-4 * np.maximum(np.abs(col[same]), floor))


def test_quadratic_exposure_jacobian_matches_central_differences():
    """The Q8 mesh of _curved rotating about a given centre and moving over the exposure: its
    Jacobian (each sub-frame on its state's curved patches, chained by R(ωτ)) against central
    differences of the oracle's curved sub-frames' mean, a mid-side node among those moved;
    test_oracle_matches_central_differences's criterion."""
    scene, meshes = _curved(mode="exact")
    mesh = meshes[0]
    scene = scene.replace(exposure={"time": 0.01, "samples": 2, "velocity": [30.0, -10.0, 0.0],
                                    "angular_velocity": [0.0, 0.0, 2.0], "centre": [0.0, 0.0, 400.0]})
    with Renderer(scene, mesh=mesh) as r:
        J = r.render(0, 1, jacobian=True).jacobian.tocsc()
        tl = motion.timeline(scene.exposure, mesh, 1)
        taus = motion.sample_offsets(scene.exposure.time, scene.exposure.samples)
        image = functools.partial(_curved_image, r, scene.cameras[0], mesh, mode="exact")
        mid = np.setdiff1d(np.unique(mesh.patches[:, :8]), mesh.patches[:, :4])
        checked = 0
        for node in (mid[len(mid) // 2], *np.random.default_rng(6).choice(np.unique(mesh.patches[:, :8]), 2, replace=False)):
            for c in range(3):
                step = DELTA * (np.arange(3) == c) * (np.arange(mesh.n_nodes) == node)[:, None]
                (plus, ep), (minus, em) = (_over_exposure(tl, taus, lambda k, d=d: mesh.deformed(k) + (d if k == 1 else 0),
                                                          lambda X: image(deformed=X)) for d in (step, -step))
                col = J[:, 3 * node + c].toarray().ravel()
                same = (ep == em) & (ep >= -1)
                floor = 1e-3 * max(np.abs(col).max(), 1e-300)
                assert np.all(np.abs((plus - minus) / (2 * DELTA) - col)[same] <= 1e-4 * np.maximum(np.abs(col[same]), floor))
                checked += np.count_nonzero(col[same])
        assert checked > 50


@pytest.mark.parametrize("extra", [{}, {"lighting": LIGHTING}, {"vignetting": CAMERA_EFFECTS["vignetting"]},
                                   {"optics": DOF, "psf": CAMERA_EFFECTS["psf"], "sensor": {"prnu": 1.5},
                                    "lighting": LIGHTING, "vignetting": CAMERA_EFFECTS["vignetting"]}],
                         ids=["plain", "lit", "vignetted", "banded"])
def test_rolling_shutter_jacobian_of_a_still_specimen_is_the_global_shutters(extra):
    """A rolling shutter's rows are rendered by one-row cameras with the rows' own states: with
    the specimen still (velocity 0) each row's Jacobian is the global shutter's row, to rounding
    (the one-row camera's rays are the full camera's), nodal and rig; lit: each row's normals'
    derivative made for that row's elements only (ShadingTerms.D); banded (depth of field and a
    PSF: each row rendered as the band of rows they reach): each row's the band's Jacobian through
    its blur and PSF (and vignetting), cut to the row, then the image's PRNU — as the global shutter's
    through the same (whose own checks are above); vignetted: the rig's gain term from each row's
    (or band's) own image before vignetting. Without the bands (the rows' one-row Jacobians
    blurred as a whole) it fails (checked)."""
    scene, mesh = _plate(backend="cpu", mode="exact", interpolation="bspline3")
    scene = scene.replace(**extra) if extra else scene
    with Renderer(scene, mesh=mesh) as r:
        still = r.render(0, 1, rig=True)
    rolling_sensor = {**extra.get("sensor", {}), "line_time": 1e-4}
    with Renderer(scene.replace(exposure={"velocity": [0.0, 0.0, 0.0]}, sensor=rolling_sensor), mesh=mesh) as r:
        rolling = r.render(0, 1, rig=True)
    for a, b in ((rolling.jacobian, still.jacobian), (rolling.rig_jacobian, still.rig_jacobian)):
        assert abs(a - b).max() <= 1e-12 * abs(b).max() and b.nnz > 1000


def test_the_psf_matrix_is_the_convolution():
    """glsim.effects.psf.matrix (the Jacobian's PSF) against scipy.ndimage's convolution
    (psf.apply), clamp to edge, for an asymmetric measured kernel: to rounding."""
    from glsim.effects import psf

    rng = np.random.default_rng(4)
    kernel = rng.uniform(0, 1, (5, 5))
    k = psf.Kernel(kernel / kernel.sum(), None)
    image = rng.uniform(0, 1, (13, 17))
    got = (psf.matrix(k, (17, 13)) @ image.ravel()).reshape(13, 17)
    np.testing.assert_allclose(got, psf.apply(image, k), rtol=0, atol=1e-15)


def test_vignetted_rig_jacobian_over_an_exposure_matches_central_differences():
    """The rig Jacobian of a vignetted image over an exposure: the gain's own change times the
    sub-frames' mean image before vignetting; the intrinsics and distortion columns (those the
    gain moves with) and the pose's against central differences of the re-calibrated camera's
    flat field times its sub-frames' mean (test_rig_jacobian_matches_central_differences's
    criterion); fails without the gain's term (checked)."""
    from glsim.effects.vignetting import flat_field

    scene, mesh = _plate(backend="cpu", mode="exact", interpolation="bspline3")
    scene = scene.replace(exposure=EXPOSURES["rigid"], vignetting=CAMERA_EFFECTS["vignetting"])
    cam = scene.cameras[0]
    with Renderer(scene, mesh=mesh) as r:
        J = r.render(0, 1, rig=True).rig_jacobian.toarray()
        tl = motion.timeline(scene.exposure, mesh, 1)
        taus = motion.sample_offsets(scene.exposure.time, scene.exposure.samples)
        for name in ("rz", "tx", "fx", "cy", "k1", "p2"):
            d = RIG_STEPS.get(name, 1e-5)
            images = []
            for v in (d, -d):
                c = _moved(cam, name, v)
                grey, one = _over_exposure(tl, taus, mesh.deformed, functools.partial(_image64, r, cam=c))
                images.append((grey * flat_field(c, scene.vignetting).ravel(), one))
            (plus, ep), (minus, em) = images
            same, col = (ep == em) & (ep >= -1), J[:, jac.RIG_COLUMNS.index(name)]
            floor = 1e-3 * np.abs(col).max()
            assert np.all(np.abs((plus - minus)[same] / (2 * d) - col[same]) <= 1e-4 * np.maximum(np.abs(col[same]), floor)), name


def test_vignetted_rig_jacobian_of_a_moving_rolling_shutter_takes_each_rows_own_image():
    """A rolling shutter with vignetting, the specimen moving: the rig Jacobian is the gain times
    the unvignetted one plus diag(image before vignetting)·∂gain/∂params, each row's image that of
    its own states (one-row cameras) — against the rendered rolling image of the same scene without
    [vignetting] (float32: 2^-24 relative, plus the Jacobians' rounding) and
    glsim.effects.vignetting's ∂gain/∂params (checked against central differences above). With the
    still image in place of the rows' own (the specimen moves between rows) the term is off by
    nearly its size (checked)."""
    from glsim.effects.vignetting import flat_field, flat_field_rig_jacobian

    scene, mesh = _plate(backend="cpu", mode="exact", interpolation="bspline3")
    moving = scene.replace(exposure=EXPOSURES["rigid"], sensor={"line_time": 2e-4})
    vignetting = CAMERA_EFFECTS["vignetting"]
    with Renderer(moving, mesh=mesh) as r:
        plain = r.render(0, 1, rig=True)
    with Renderer(moving.replace(vignetting=vignetting), mesh=mesh) as r:
        vignetted = r.render(0, 1, rig=True)
        cam, v = r.scene.cameras[0], r.scene.vignetting
    term = plain.image.astype(np.float64).reshape(-1, 1) * flat_field_rig_jacobian(cam, v)
    want = flat_field(cam, v).reshape(-1, 1) * plain.rig_jacobian.toarray() + term
    bound = 2.0 ** -23 * np.abs(term) + 1e-12 * np.abs(want).max(axis=0)   # the image's float32, the sums' rounding
    assert np.all(np.abs(vignetted.rig_jacobian.toarray() - want) <= bound)
    assert np.abs(term).max() > 1e4 * bound.max()   # (the gain's term is checked, not lost in the bound)


@pytest.mark.parametrize("change, key", [({"psf": {"kind": "gaussian", "sigma": 0.9}}, "psf"), ({"optics": DOF}, "optics")])
def test_a_jacobian_over_the_memory_budget_is_refused_by_name(monkeypatch, change, key):
    """Through the PSF or the depth of field the Jacobian holds up to a window's times the
    raster's entries: where that exceeds what the process may use (here a budget of 1 MiB) the
    table is named with the fix, before the product is made."""
    monkeypatch.setattr("glsim.limits.memory_budget", lambda: 1 << 20)
    scene, mesh = _plate(backend="cpu")
    with Renderer(scene.replace(**change), mesh=mesh) as r, \
            pytest.raises(SceneError, match=rf"^{key}: the image Jacobian through .* GiB, more than .* — render a smaller camera"):
        r.render(0, 1, jacobian=True)


def test_a_fill_factor_at_one_sample_per_pixel_leaves_the_jacobian_unchanged():
    """At 1 sample per pixel the sample is the pixel's centre whatever the fill factor
    (glsim.scene.camera.pixel_grid), so image and Jacobian are those of a full pixel."""
    scene, mesh = _plate(backend="cpu")
    out = []
    for ff in (1.0, 0.5):
        with Renderer(scene.replace(sensor={"fill_factor": ff}), mesh=mesh) as r:
            out.append(r.render(0, 1, jacobian=True))
    assert np.array_equal(out[0].image, out[1].image) and abs(out[0].jacobian - out[1].jacobian).max() == 0
    assert out[0].jacobian.nnz > 0


def test_a_hard_edged_speckle_is_refused_by_name_and_noise_left_out():
    scene, mesh = _plate(backend="cpu")
    with Renderer(scene, mesh=mesh) as r:
        J = r.render(0, 1, jacobian=True).jacobian
    with Renderer(scene.replace(speckle={"edge_px": 0.0}), mesh=mesh) as r, \
            pytest.raises(SceneError, match=r"^speckle\.edge_px: is 0: .* — give the dots a smooth edge"):
        r.render(0, 1, jacobian=True, interpolation="procedural")
    with Renderer(scene.replace(noise={"sigma": 1.0}), mesh=mesh) as r:   # the noise-free image's Jacobian
        assert abs(r.render(0, 1, jacobian=True).jacobian - J).max() == 0


@pytest.mark.gl
@pytest.mark.parametrize("mode, spp, interpolation", [("exact", 1, "cubic"), ("q4", 1, "cubic"), ("exact", 4, "cubic"),
                                                      ("exact", 1, "procedural")])
def test_gl_matches_the_oracle(gl_ctx, mode, spp, interpolation):
    _gl_against_oracle(gl_ctx, *_plate(mode=mode, samples_per_pixel=spp, interpolation=interpolation))


@pytest.mark.gl
def test_gl_matches_the_oracle_through_camera_effects(gl_ctx):
    """Vignetting, the PSF and fixed-pattern noise (the rig's vignetting-gain term from each
    backend's own image before the camera effects): as above."""
    scene, mesh = _plate()
    _gl_against_oracle(gl_ctx, scene.replace(**CAMERA_EFFECTS), mesh)


@pytest.mark.gl
@pytest.mark.parametrize("spp", [1, 4])
def test_gl_matches_the_oracle_over_an_exposure(gl_ctx, spp):
    """A rigid motion over the exposure (the sub-frames' rasters from GL; at 4 spp each
    sub-frame's sample camera rendered in its state): as above."""
    scene, mesh = _plate(samples_per_pixel=spp)
    _gl_against_oracle(gl_ctx, scene.replace(exposure=EXPOSURES["rigid"]), mesh)


def _gl_against_oracle(gl_ctx, scene, mesh):
    """GL's nodal and rig Jacobians within 1e-3 of the oracle's largest entry."""
    out = {}
    for backend in ("cpu", "gl"):
        with Renderer(scene, backend, ctx=gl_ctx if backend == "gl" else None, mesh=mesh) as r:
            res = r.render(0, 1, rig=True)
            out[backend], out[backend + " rig"] = res.jacobian, res.rig_jacobian
    assert abs(out["gl"] - out["cpu"]).max() <= 1e-3 * abs(out["cpu"]).max()
    assert abs(out["gl rig"] - out["cpu rig"]).max() <= 1e-3 * abs(out["cpu rig"]).max()


@pytest.mark.gl
def test_gl_matches_the_oracle_with_a_fill_factor(gl_ctx):
    """A fill factor of 0.5 at 4 samples per pixel (the samples rendered as shifted cameras by
    each backend): as above."""
    scene, mesh = _plate(samples_per_pixel=4)
    _gl_against_oracle(gl_ctx, scene.replace(sensor={"fill_factor": 0.5}), mesh)


@pytest.mark.gl
@pytest.mark.slow   # the oracle renders each band's image
def test_gl_matches_the_oracle_with_a_banded_rolling_shutter(gl_ctx):
    """A rolling shutter with the depth of field and a PSF (each row's band's Jacobian), the
    plate moving rigidly: as above."""
    scene, mesh = _plate()
    _gl_against_oracle(gl_ctx, scene.replace(optics=DOF, psf=CAMERA_EFFECTS["psf"], sensor={"line_time": 2e-5},
                                             exposure={**EXPOSURES["rigid"], "samples": 1}), mesh)


@pytest.mark.gl
@pytest.mark.parametrize("spp", [1, 4])
def test_gl_matches_the_oracle_through_the_depth_of_field(gl_ctx, spp):
    """The depth of field over an exposure (each sub-frame blurred with its own depths; GL's
    unblurred image is float32, as the oracle's, and its blur scheme does not enter: the
    Jacobian is of the oracle's gather), lit: as above."""
    scene, mesh = _plate(samples_per_pixel=spp)
    _gl_against_oracle(gl_ctx, scene.replace(optics=DOF, lighting=LIGHTING, exposure=EXPOSURES["rigid"]), mesh)


@pytest.mark.gl
@pytest.mark.parametrize("case", ["plain", "lit", "depth of field", "Q8"])
def test_gl_matches_the_oracle_in_mode_fast(gl_ctx, case):
    """Mode fast at 4 samples per pixel: GL's Jacobian (its rasterizer's elements, the derivatives
    from the sample points) within 1e-3 of the oracle's largest entry on every pixel whose 16
    samples fall in the same elements in both backends' rasters — the rasterizer snaps vertices
    to its sub-pixel grid, so a sample on an edge may go to the other element (docs/hard_cases.md);
    with the depth of field, pixels within the blur's reach of such a sample left out too."""
    from scipy.ndimage import binary_dilation

    if case == "Q8":
        scene, (mesh, _) = _curved(mode="fast", samples_per_pixel=4)
    else:
        scene, mesh = _plate(mode="fast", samples_per_pixel=4)
        scene = scene.replace(**{"plain": {}, "lit": {"lighting": {**LIGHTING, "combine": "multiplicative"}},
                                 "depth of field": {"optics": DOF}}[case])
    cam, out = scene.cameras[0], {}
    W, H = cam.size
    for backend in ("cpu", "gl"):
        with Renderer(scene, backend, ctx=gl_ctx if backend == "gl" else None, mesh=mesh) as r:
            res = r.render(0, 1, rig=True)
            view = r.geometry.view(jac.sample_camera(cam, 4), 1)
            one = dataclasses.replace(r.scene.render, samples_per_pixel=1)
            el = r.backend.render(Request(view, one, truth=True, polish=False)).samples["element"]
            out[backend] = (res.jacobian, res.rig_jacobian, el.reshape(H, 4, W, 4).transpose(0, 2, 1, 3).reshape(H, W, 16))
            if case == "depth of field" and backend == "cpu":   # the blur windows' largest radius
                reach = int(_blurred64(r, mesh.deformed(1))[2].max())
    differ = (out["cpu"][2] != out["gl"][2]).any(-1)
    if case == "depth of field":
        differ = binary_dilation(differ, np.ones((3, 3), bool), iterations=reach)
    keep = ~differ.ravel()
    assert keep.mean() > 0.8   # (most of the image compared)
    for k in (0, 1):
        a, b = out["cpu"][k][keep], out["gl"][k][keep]
        assert abs(b - a).max() <= 1e-3 * abs(a).max()


@pytest.mark.gl
@pytest.mark.parametrize("mode, spp", [("exact", 1), ("exact", 4)])
def test_gl_matches_the_oracle_with_lighting(gl_ctx, mode, spp):
    """Lit (smooth normals, multiplicative), over an exposure (each sub-frame's normals in its
    state): as above."""
    scene, mesh = _plate(mode=mode, samples_per_pixel=spp)
    _gl_against_oracle(gl_ctx, scene.replace(lighting={**LIGHTING, "combine": "multiplicative"},
                                             exposure=EXPOSURES["rigid"]), mesh)


@pytest.mark.gl
@pytest.mark.parametrize("mode, spp", [("exact", 1), ("q4", 1), ("exact", 4)])
def test_gl_matches_the_oracle_on_quadratic_elements(gl_ctx, mode, spp):
    """As test_gl_matches_the_oracle, on the Q8 and T6 meshes of _curved (GL's curved truth is
    polished in float64, so its raster is the oracle's to Newton's tolerance)."""
    scene, meshes = _curved(mode=mode, samples_per_pixel=spp)
    for mesh in meshes:
        _gl_against_oracle(gl_ctx, scene, mesh)


@pytest.mark.gl
@pytest.mark.parametrize("spp", [1, 4])
def test_gl_matches_the_oracle_on_lit_quadratic_elements(gl_ctx, spp):
    """The Q8 mesh of _curved lit (the pieces' smooth normals, multiplicative): as above."""
    scene, meshes = _curved(mode="exact", samples_per_pixel=spp, pieces=3)
    _gl_against_oracle(gl_ctx, scene.replace(lighting={**LIGHTING, "combine": "multiplicative"}), meshes[0])


@pytest.mark.gl
@pytest.mark.parametrize("spp", [1, 4])
def test_gl_matches_the_oracle_on_quadratic_elements_over_an_exposure(gl_ctx, spp):
    """The Q8 mesh of _curved moving rigidly over the exposure (each sub-frame's curved patches
    in its own state; at 4 spp its sample camera rendered so): as test_gl_matches_the_oracle."""
    scene, meshes = _curved(mode="exact", samples_per_pixel=spp)
    _gl_against_oracle(gl_ctx, scene.replace(exposure={"time": 0.01, "samples": 2, "velocity": [30.0, -10.0, 0.0],
                                                       "angular_velocity": [0.0, 0.0, 1.0]}), meshes[0])


def test_quadratic_rig_jacobian_matches_central_differences():
    """test_rig_jacobian_matches_central_differences on the Q8 mesh of _curved, exact mode: every
    camera parameter, the curved raster re-rendered with the camera moved ±d."""
    scene, (mesh, _) = _curved(mode="exact", interpolation="bspline3")
    cam = dataclasses.replace(scene.cameras[0], skew=0.7, R=rodrigues(np.array([0.02, -0.03, 0.01])),
                              t=(1.0, -0.5, 3.0), distortion=Distortion(k1=-0.2, p1=1e-3, k4=0.05, s1=0.01))
    with Renderer(scene.replace(cameras=(cam,)), mesh=mesh) as r:
        J = r.render(0, 1, rig=True).rig_jacobian.toarray()

        def image(c):
            return _curved_image(r, c, mesh, mesh.deformed(1), "exact")
        for col, name in enumerate(jac.RIG_COLUMNS):
            d = RIG_STEPS.get(name, 1e-5)
            (plus, ep), (minus, em) = image(_moved(cam, name, d)), image(_moved(cam, name, -d))
            same = (ep == em) & (ep >= 0)
            fd = (plus - minus)[same] / (2 * d)
            floor = 1e-3 * np.abs(J[:, col]).max()
            assert floor > 0 and np.all(np.abs(fd - J[same, col]) <= 1e-4 * np.maximum(np.abs(J[same, col]), floor)), name


PLATE_TOML = """
[[cameras]]
name = "left"
size = [48, 36]
fx = 700.0
fy = 700.0
cx = 23.5
cy = 17.5

[specimen.plate]
width = 20.0
height = 15.0
nx = 4
ny = 3
translations = [[0.1, 0.05, 0.0]]

[specimen.pose]
t = [0.0, 0.0, 300.0]

[render]
backend = "cpu"
interpolation = "cubic"
"""


def test_cli_round_trip(tmp_path, capsys):
    path = tmp_path / "plate.toml"
    path.write_text(PLATE_TOML)
    out = tmp_path / "J.npz"
    assert cli.main(["jacobian", str(path), "--camera", "left", "--step", "1", "-o", str(out), "--rig"]) == 0
    assert "wrote" in capsys.readouterr().out
    J = sp.load_npz(out)
    with Renderer(load_scene(path)) as r:
        res = r.render("left", 1, rig=True)
        labels = r.mesh.node_labels
    assert abs(J - res.jacobian).max() == 0 and J.shape == (48 * 36, 3 * len(labels))
    with np.load(out) as f:
        assert np.array_equal(f["node_labels"], labels) and str(f["camera"]) == "left" and int(f["step"]) == 1
        np.testing.assert_array_equal(f["image"], res.image)
        G = sp.csr_matrix((f["rig_data"], f["rig_indices"], f["rig_indptr"]), shape=(48 * 36, 23))
        assert abs(G - res.rig_jacobian).max() == 0 and list(f["rig_columns"]) == list(jac.RIG_COLUMNS)
    for args, message in ((["--camera", "right", "--step", "1"], "camera: no camera named 'right'"),
                          (["--step", "5"], "step: 5 is outside")):
        bad = tmp_path / "bad.npz"
        assert cli.main(["jacobian", str(path), *args, "-o", str(bad)]) == 2
        assert f"glsim: error: {message}" in capsys.readouterr().err
        assert not bad.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["J.npz", "plate.toml"]


def test_identify_plate_example_recovers_the_stretch(capsys):
    """examples/identify_plate.py, three Gauss–Newton steps: within 3 Cramér–Rao std of the truth."""
    path = Path(__file__).resolve().parents[1] / "examples" / "identify_plate.py"
    spec = importlib.util.spec_from_file_location("identify_plate", path)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    out = example.main(["--iterations", "3"])
    assert abs(out["error"]) < 3 * out["crb"] and out["crb"] < 1e-5
    assert "finite differences" in capsys.readouterr().out
