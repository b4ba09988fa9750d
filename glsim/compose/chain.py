"""The Jacobian chain (docs/jacobian.md): the noise-free image's derivative with respect to the
nodal displacements (and, with ``rig``, the camera's parameters) from the backend's float64
raster of every sample (:func:`glsim.imaging.jacobian.image_jacobian`), chained through what
lies between that raster and the image, each link the derivative beside its forward:

1. a quadratic mesh drawn as its pieces (mode fast): the pieces' nodes as weights of the mesh's;
2. the depth of field's blur (:func:`glsim.effects.dof.through_blur`, of the state's unblurred image);
3. an exposure's state at τ: ∂X(τ)/∂X_k (:meth:`glsim.effects.motion.Timeline.derivative`);
4. the camera effects that act on the image linearly, in the pipeline's order (docs/camera.md):
   vignetting (:func:`glsim.effects.vignetting.through_flat_field`), the lens PSF
   (:func:`glsim.effects.psf.through_kernel`), the PRNU (:func:`glsim.effects.noise.through_prnu`).
"""
from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import numpy as np
from scipy import sparse

from glsim.backends.contract import Request
from glsim.compose.drawing import Drawing
from glsim.effects import dof, motion, shading_terms
from glsim.scene import Render, Scene
from glsim.scene.camera import Camera
from glsim.imaging import interp, jacobian as jac
from glsim.imaging.reference import require_dots

CAMERA_STAGES = ("vignetting", "psf", "prnu")


def jacobians(d: Drawing, cam: Camera, step: int, opts: Render, raster: dict | None, rig: bool) -> dict:
    """``jacobian`` and ``rig_jacobian`` (None unless ``rig``) of ``cam``'s image at ``step``
    (:func:`raster_jacobian` through the camera effects; ``raster``: the image's own, or None)."""
    J, J_rig = raster_jacobian(d, cam, step, opts, raster, rig)
    return through_camera(d, cam, J, J_rig, gain_term=gain_term(d, cam, step, opts, rig))


def raster_jacobian(d: Drawing, cam: Camera, step: int, opts: Render, raster: dict | None, rig: bool,
                    tl: motion.Timeline | None = None, tau: float = 0.0):
    """(J, J_rig) of ``cam``'s image before the camera effects, from the backend's float64 raster
    of every sample (``raster``, or None: for s > 1 rendered as the pixels of the finer sample
    camera, its warnings were the image's). ``tl``: of the state τ s from the step's time (an
    exposure's sub-frame), chained to the step's own displacements by the state's derivative."""
    s, mesh, drawn_mesh, scene = opts.supersampling, d.mesh, d.drawn_mesh, d.scene
    state = None if tl is None or tau == 0 else float(tau)
    deformed = mesh.deformed(step) if tl is None else tl.at(tau, mesh.deformed)
    drawn = drawn_mesh.deformed(step) if tl is None else tl.at(tau, drawn_mesh.deformed)
    aperture = math.sqrt(scene.sensor.fill_factor) if scene.sensor is not None else 1.0
    if raster is None:
        raster = _sample_raster(d, cam, step, opts, None if tl is None else drawn, state, tl, tau, aperture)
    value, gradient = reference_functions(d, opts.interpolation)
    pieces = opts.mode == "fast" and mesh.is_quadratic   # fast draws the pieces: their nodes, then chained
    of = drawn_mesh if pieces else mesh                  # the mesh differentiated
    shading = None
    if scene.lighting is not None:   # the drawn mesh's normals (a quadratic mesh's pieces')
        shading = shading_terms(scene, drawn, drawn_mesh.quads, cam, value, None if pieces else d.pieces)
    J, J_rig, depth = jac.image_jacobian(
        cam, d.reference.camera, jac.MeshState(of.nodes, drawn if pieces else deformed, of.quads, of.patches),
        raster, gradient, jac.JacobianOptions(opts.mode, s, aperture, rig, scene.optics is not None), shading)
    if pieces:   # the pieces' nodes as weights of the mesh's (PiecesMesh.grid_matrix)
        G = sparse.kron(drawn_mesh.grid_matrix(), sparse.identity(3), format="csr")
        J = J @ G
        depth = None if depth is None else (depth[0], depth[1] @ G, depth[2])
    if depth is not None:   # through the depth of field's blur, of this state's unblurred image
        z, J_z, J_z_rig = depth
        W, H = cam.size
        n = J.shape[1]
        out = dof.through_blur(J if J_rig is None else sparse.hstack([J, J_rig], format="csr"),
                               J_z if J_rig is None else sparse.hstack([J_z, J_z_rig], format="csr"),
                               image_before(d, cam, step, opts, tl, tau, blur=False), dof.pixel_depth(z, H, W, s),
                               scene.optics)
        J, J_rig = (out, None) if J_rig is None else (out[:, :n], out[:, n:])
    if tl is not None:   # ∂g/∂u_k = ∂g/∂X(τ) · ∂X(τ)/∂X_k, per node
        J = J @ sparse.kron(sparse.identity(mesh.n_nodes), tl.derivative(tau), format="csr")
    return J, J_rig


def _sample_raster(d: Drawing, cam: Camera, step: int, opts: Render, drawn_state, state, tl, tau: float,
                   aperture: float) -> dict:
    """The float64 raster of ``cam``'s s × s samples (flat, in the sample camera's order),
    rendered at 1 spp as the sample camera's pixels or, with a fill factor, as cameras shifted
    by each sample offset; its warnings were the image's."""
    s = opts.supersampling
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = dataclasses.replace(opts, samples_per_pixel=1)
        curved = d.curved(opts, step, tl, tau)
        polish = opts.mode != "fast"   # (fast's Jacobian uses the raster's elements only)
        if aperture == 1.0:
            view = d.geometry.view(jac.sample_camera(cam, s), step, state, drawn_state)
            return d.render(Request(view, one, True, curved=curved, polish=polish)).samples
        # each sample offset as a camera shifted by it: (H, s, W, s) → the sample camera's order
        parts = [[d.render(Request(d.geometry.view(shifted, step, state, drawn_state), one, True, curved=curved,
                                   polish=polish)).samples for shifted in row]
                 for row in jac.shifted_cameras(cam, s, aperture)]
        W, H = cam.size
        return {k: np.stack([np.stack([p[k].reshape(H, W) for p in row], -1) for row in parts], 1).reshape(-1)
                for k in ("element", "xi", "eta")}


def through_camera(d: Drawing, cam: Camera, J, J_rig, stages=None, gain_term=None) -> dict:
    """``jacobian`` and ``rig_jacobian`` of ``cam``'s image from the raster's (J, J_rig) through
    the camera effects (:func:`through_camera_effects`; ``stages``: only those; ``gain_term``: the
    rig Jacobian's vignetting-gain share, :func:`gain_term`)."""
    index = d.camera_index(cam)
    return {"jacobian": through_camera_effects(J, d.scene, cam, index, stages),
            "rig_jacobian": None if J_rig is None else through_camera_effects(J_rig, d.scene, cam, index, stages,
                                                                              gain_term)}


def through_camera_effects(J, scene: Scene, cam: Camera, camera_index: int, stages=None, gain_term=None):
    """An image Jacobian ``J`` (W·H × n, sparse) of the image before the camera effects → of the
    image after those of them that act on it linearly and do not move with the nodes, in the
    pipeline's order: vignetting, the lens PSF, the PRNU; ``stages``: only those of CAMERA_STAGES
    (a rolling shutter's band takes vignetting and the PSF, its whole image the PRNU);
    ``gain_term``: what the vignetting gain's own change adds after its stage."""
    W, H = cam.size
    stages = CAMERA_STAGES if stages is None else stages
    if scene.vignetting is not None and "vignetting" in stages:
        from glsim.effects.vignetting import through_flat_field

        J = through_flat_field(J, cam, scene.vignetting, gain_term)
    if scene.psf is not None and "psf" in stages:
        from glsim.effects import psf

        J = psf.through_kernel(J, psf.make_kernel(scene.psf, Path(scene.base_dir)), (W, H))
    if scene.sensor is not None and scene.sensor.prnu > 0 and "prnu" in stages:
        from glsim.effects import noise

        J = noise.through_prnu(J, (H, W), scene.sensor.prnu, noise.fixed_pattern_seed(scene.seed, camera_index))
    return sparse.csr_matrix(J)


def gain_term(d: Drawing, cam: Camera, step: int, opts: Render, rig: bool, tl=None, taus=(0.0,), rows=None):
    """The rig Jacobian's share of the vignetting gain's own change with the intrinsics and
    distortion: diag(the image before vignetting) · ∂gain/∂params (W·H × 23, CSR), or None;
    over an exposure (``tl``) the image is its sub-frames' (at ``taus``) mean; ``rows``: a
    rolling shutter's (row, time offset) pairs, each row's image its own sub-frames' (one-row
    cameras)."""
    if not rig or d.scene.vignetting is None:
        return None
    from glsim.effects.vignetting import flat_field_rig_jacobian

    parts = [(cam, 0.0)] if rows is None else [(motion.row_band(cam, row)[0], t) for row, t in rows]
    before = np.concatenate([sum(image_before(d, c, step, opts, tl, t + tau, blur=True).ravel() for tau in taus)
                             for c, t in parts]) / len(taus)
    return sparse.csr_matrix(before.reshape(-1, 1) * flat_field_rig_jacobian(cam, d.scene.vignetting))


def image_before(d: Drawing, cam: Camera, step: int, opts: Render, tl, tau: float, blur: bool) -> np.ndarray:
    """``cam``'s image (H, W) float64 at ``step`` (or the state τ s from it on ``tl``) before
    the camera effects and noise: lit, supersampled, and with its depth of field if ``blur``."""
    state = None if tl is None or tau == 0 else float(tau)
    nodes = d.drawn_mesh.deformed(step) if tl is None else tl.at(tau, d.drawn_mesh.deformed)
    view = d.geometry.view(cam, step, state, None if tl is None else nodes)
    fx = d.effects(cam, step, nodes, view.corner_depths())
    fx = dataclasses.replace(fx, noise=None, sensor=None, vignette=None, psf=None,
                             **({} if blur else {"optics": None, "sigma_max": 0.0}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = d.render(Request(view, opts, False, fx, d.curved(opts, step, tl, tau)))
    return out.image.astype(np.float64)


def reference_functions(d: Drawing, method: str):
    """The reference grey's value and gradient (grey per px) at reference points uv (n, 2), in
    float64: the interpolant of ``method`` (its coefficients made once per renderer), or the
    procedural speckle's exact dots (glsim.scene.speckle.evaluate, gradient)."""
    if method == "procedural":
        from glsim.scene import speckle

        dots = require_dots(d.reference.dots)
        grid = speckle.dot_grid(dots)
        return (lambda uv: speckle.evaluate(dots, uv, grid)), (lambda uv: speckle.gradient(dots, uv, grid))
    if method not in d.coeffs:
        d.coeffs[method] = interp.prepare(d.reference.image, method, np.float64)
    coeffs = d.coeffs[method]
    return (lambda uv: interp.sample(coeffs, uv, method)), (lambda uv: interp.gradient(coeffs, uv, method))
