"""Bounds over a scene's pixels, from the CPU oracle's own maps of it: each function takes a
renderer (GL, for its mesh and rasterizer, or the oracle, whose truth, reference and images it
reads or renders) and evaluates the closed forms of :mod:`glsim.check.closed_forms` per pixel —
the coverage ties (:func:`renderer_ties`), the grey levels of an image without effects
(:func:`renderer_grey`), the float32 q4 build (:func:`renderer_q4_fp32`), and each effect on top:
lighting (:func:`renderer_lit`), motion over the exposure (:func:`renderer_motion`), depth of
field (:func:`renderer_dof`) and sensor noise (:func:`renderer_noise`)."""
from __future__ import annotations

import numpy as np

from glsim.check.closed_forms import (FLOAT32_ROUNDOFF, FLOAT64, blur, coc, disk_ramp, f32_error, fast_bound,
                                      fast_px, gradient_max, grey, mapping, near_edges, noise, normal_field,
                                      per_pixel, phong, q4_fp32_px, sample_gradient, tie_px)


def renderer_ties(renderer, mode: str, cam: int, step: int, spp: int = 1, radius=None) -> np.ndarray:
    """Camera ``cam``'s pixels at ``step`` where a GL renderer's image, mask or element map may
    differ from the oracle's by a sample decided the other way: :func:`near_edges` within
    ``mode``'s :func:`tie_px` (its mesh, its rasterizer's GL_SUBPIXEL_BITS; exact and q4 as
    float64 builds, whose ties are float64's), or within ``radius`` (:func:`near_edges`' per
    edge function of the step's nodes in the camera's frame: the float32 exact build's,
    :func:`glsim.check.exact32.renderer_ties`); with the scene's depth of field, grown by the blur's reach
    (a sample decided the other way changes every pixel whose kernel takes it in: the largest
    kernel radius over the specimen's depths, which lie between its nodes')."""
    from glsim.effects import dof
    from glsim.scene.camera import to_camera

    if renderer.mesh.is_quadratic:
        raise ValueError("renderer_ties: a quadratic mesh's element edges are curved in space; "
                         "its ties are not derived here (linear meshes only)")
    camera, nodes = renderer.scene.cameras[cam], renderer.mesh.deformed(step)
    if radius is None:
        radius = tie_px(mode, camera.fx, renderer.backend.capabilities.subpixel_bits)
    else:
        Pc, per_edge = to_camera(nodes, camera), radius
        radius = lambda a, b: per_edge(Pc[a], Pc[b])   # noqa: E731
    tie = near_edges(camera, nodes, renderer.mesh.quads, radius, spp, exact=mode == "exact")
    optics = renderer.scene.optics
    if optics is None or not tie.any():
        return tie
    size = dof.blur_sigma(to_camera(nodes, camera)[:, 2], optics).max()
    reach = int(dof.kernel_radius(size, getattr(optics, "kernel", "gaussian")))
    if reach == 0:
        return tie
    import cv2

    return cv2.dilate(tie.astype(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)).astype(bool)


def renderer_q4_fp32(renderer, cam: int, step: int) -> tuple[float, np.ndarray]:
    """For a GL renderer's float32 q4 build, camera ``cam`` at ``step``: (:func:`q4_fp32_px`,
    its ties — the pixels with a sample within that distance of an element edge, where its
    coverage and element may differ from the oracle's: :func:`renderer_ties`)."""
    camera, mesh = renderer.scene.cameras[cam], renderer.mesh
    px = q4_fp32_px(camera, mesh.deformed(step), mesh.quads)
    return px, renderer_ties(renderer, "q4", cam, step, radius=lambda Pa, Pb: np.full(len(Pa), px + FLOAT64))


def renderer_grey(oracle, mode: str, cam: int, step: int, spp: int, shift, truth=None):
    """Per pixel, :func:`grey` of the oracle renderer ``oracle``'s image of camera ``cam`` at
    ``step`` in ``mode`` at ``spp``, GL's reference points within ``shift`` px (a number or per
    pixel) of the oracle's, with the interpolant's gradient at the oracle's sample reference
    points: at 1 spp the pixel centres' (``truth``: the oracle's truth of that image); fast at
    s × s spp its samples' (:func:`sample_truth`); exact and q4, whose points move by float64
    rounding only, the interpolant's largest gradient."""
    method, coeffs, M = _reference(oracle)
    s = int(round(np.sqrt(spp)))
    if s == 1:
        grad = sample_gradient(method, coeffs, truth.ref_uv, truth.mask)
    elif mode == "fast":
        t = sample_truth(oracle, mode, cam, step, spp)[1]
        grad = sample_gradient(method, coeffs, t.ref_uv, t.mask, s)
    else:
        grad = gradient_max(method) * M
    return grey(method, M, grad, shift, spp)


def _reference(oracle):
    """The oracle's interpolation, its coefficients of the reference image (float64) and their
    largest |value|."""
    from glsim.imaging import interp

    method = oracle.scene.render.interpolation
    coeffs = interp.prepare(oracle.reference.image, method, np.float64)
    return method, coeffs, float(np.abs(coeffs).max())


def sample_truth(oracle, mode: str, cam: int, step: int, spp: int):
    """(camera, truth): the oracle's truth at the s × s samples of camera ``cam`` at ``step`` in
    ``mode`` — at 1 spp its own; else that of a camera added to the scene whose pixel centres
    are those samples (scaled_camera by s, named glsim-samples-cam; camera 0, which sets the
    speckle's scale, kept)."""
    import dataclasses

    from glsim.render import Renderer
    from glsim.workflows.preview.layout import scaled_camera

    s = int(round(np.sqrt(spp)))
    cams = oracle.scene.cameras
    if s == 1:
        return cams[cam], oracle.render(cam, step, truth=True, mode=mode).truth
    fine = dataclasses.replace(scaled_camera(cams[cam], s), name=f"glsim-samples-{cam}")
    with Renderer(oracle.scene.replace(cameras=cams + (fine,)), "cpu", mesh=oracle.mesh) as r:
        return fine, r.render(len(cams), step, truth=True, mode=mode).truth


def _pixel_points(oracle, camera, step: int, truth, who: str):
    """The oracle's covered pixels of ``camera`` at ``step`` (``truth`` of that view, 1 spp):
    their elements, the shape functions at their (ξ, η) (n, 4), their elements' corners and
    points in the camera's frame (n, 4, 3), (n, 3), mm; linear elements only (``who`` refuses)."""
    from glsim.scene import bilinear as bl
    from glsim.imaging.view import make_view

    mesh = oracle.mesh
    if mesh.is_quadratic:
        raise ValueError(f"{who}: linear elements only (a quadratic mesh's point lies on its curved patch)")
    view = make_view(camera, oracle.reference.camera, mesh.nodes, mesh.deformed(step), mesh.quads, warn=False)
    m = truth.mask
    e = truth.element[m]
    w = bl.shape_functions(truth.xi[m], truth.eta[m])
    P = view.Xd[e]
    return e, w, P, np.einsum("ni,nik->nk", w, P)


def renderer_lit(oracle, mode: str, cam: int, step: int, spp: int = 1) -> np.ndarray:
    """Per pixel (H, W), how far a GL renderer's lit image may lie from the oracle renderer
    ``oracle``'s of camera ``cam`` at ``step`` in ``mode`` at ``spp``, first order
    in u = 2^-24, per sample (the oracle's, :func:`sample_truth`): the unlit sample's bound
    (:func:`grey` at GL's reference points within :func:`mapping` of the oracle's) through the
    combine (additive: 1, multiplicative: |I|); shade.glsl's float32 lighting and combine on
    float32 inputs (:func:`phong`); and those inputs' own errors through |∂I/∂X|, |∂I/∂N|
    (glsim.effects.lighting.phong_gradient) — shading.glsl's light_at: the point Σ wᵢ Pᵢ from the
    nodes in the camera frame as float32 (each node, weight, product and sum rounded:
    8u·Σ|wᵢ||Pᵢ|), the normal Σ wᵢ nᵢ of the float32 corner normals turned by the float32
    rotation (12u) and normalised (16u); on a quadratic mesh (exact, q4) the point on the
    curved patch from its nine nodes (12u·Σ|Nᵢ||Pᵢ|) and the normal over the linear piece holding
    it; in fast the (ξ, η) it interpolates, within fast's vertex bound (:func:`fast_px`) times
    the point's and the normal's change per sample (:func:`per_pixel`). At n = s² > 1 spp a pixel takes its samples' largest and the box
    filter's n − 1 float32 adds and division, (n + 4)u of the largest lit value."""
    from glsim.effects import lighting as shade
    from glsim.effects import prepare

    u, lit, mesh = FLOAT32_ROUNDOFF, oracle.scene.lighting, oracle.mesh
    camera, truth = sample_truth(oracle, mode, cam, step, spp)
    method, coeffs, M = _reference(oracle)
    m = truth.mask
    shift = mapping(mode, camera.fx, truth.ref_uv, m)
    unlit = grey(method, M, sample_gradient(method, coeffs, truth.ref_uv, m), shift)
    if mesh.is_quadratic:   # the point on the curved patch (9 nodes), the normal over its piece
        if mode == "fast":
            raise ValueError("renderer_lit: a quadratic mesh in fast mode (its pieces' lighting) is not derived here")
        from glsim.scene import bilinear as bl
        from glsim.scene import quadratic as qd
        from glsim.imaging.quadview import make_quad_view

        deformed = mesh.deformed(step)
        drawn = oracle.pieces.mesh.at_grid(deformed)
        view = make_quad_view(camera, oracle.reference.camera, mesh.nodes, deformed, mesh.patches, warn=False,
                              pieces=oracle.pieces, pieces_def=drawn, mode=mode)
        e, xi, eta = truth.element[m], truth.xi[m], truth.eta[m]
        P, wq = view.Pd[e], qd.shape_functions(xi, eta)
        X = qd.evaluate(P, xi, eta)
        piece, xs, ys = qd.piece_of(e, xi, eta, view.pieces)
        fx = prepare(oracle.scene, drawn, oracle.pieces.mesh.quads, camera, cam, step, np.empty(0))
        e, w = piece, bl.shape_functions(xs, ys)
        dX = 12 * u * np.einsum("ni,ni->n", np.abs(wq), np.linalg.norm(P, axis=-1))
    else:
        e, w, P, X = _pixel_points(oracle, camera, step, truth, "renderer_lit")
        fx = prepare(oracle.scene, mesh.deformed(step), mesh.quads, camera, cam, step, np.empty(0))
        dX = 8 * u * np.einsum("ni,ni->n", np.abs(w), np.linalg.norm(P, axis=-1))
    N = np.einsum("ni,nik->nk", w, fx.normals[e])
    args = (fx.lights, lit.ambient, lit.diffuse, lit.specular, lit.shininess)
    I, dI_X, dI_N, _ = shade.phong_gradient(X, N, *args)
    g = oracle.backend.sampler(method)(truth.ref_uv[m])
    dN = 28 * u * np.einsum("ni,ni->n", np.abs(w), np.linalg.norm(fx.normals[e], axis=-1))
    if mode == "fast":   # GL's (ξ, η) interpolated over its float32 triangles

        def moved(field):
            full = np.zeros(m.shape + (3,))
            full[m] = field
            return per_pixel(full, m)[m] * fast_px(camera.fx)
        dX, dN = dX + moved(X), dN + moved(N)
    multiplicative = lit.combine == "multiplicative"
    out = np.zeros(m.shape)
    out[m] = ((np.abs(I) if multiplicative else 1.0) * (unlit[m] if np.ndim(unlit) else unlit)
              + phong(X, N, *args, grey=g, model=lit.combine)
              + (np.abs(g) if multiplicative else 1.0) * (np.linalg.norm(dI_X, axis=-1) * dX
                                                         + np.linalg.norm(dI_N, axis=-1) * dN))
    s = int(round(np.sqrt(spp)))
    if s == 1:
        return out
    top = float(np.abs(g * I if multiplicative else g + I).max(initial=0.0))
    Hs, Ws = m.shape
    return out.reshape(Hs // s, s, Ws // s, s).max(axis=(1, 3)) + (spp + 4) * u * top


def without(oracle, effect: str, mode: str, cam: int, step: int, spp: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The oracle renderer ``oracle``'s image of camera ``cam`` at ``step`` in ``mode`` at ``spp``
    with ``effect`` ("noise" or "optics", the scene's only effect) left out, and the bound of a
    GL renderer's against it per pixel (:func:`renderer_grey`: GL's reference points within
    :func:`mapping` of the oracle's; at 1 spp 0 off the oracle's mask, the background both
    draw): what :func:`renderer_noise` and :func:`renderer_dof` start from."""
    import dataclasses

    from glsim.render import Renderer

    others = [e for e in ("lighting", "optics", "noise") if e != effect and getattr(oracle.scene, e) is not None]
    if others or (spp > 1 and mode == "fast"):
        raise ValueError(f"without: derived for {effect} alone, exact or q4 at several samples per pixel "
                         f"(the scene has {others}, mode {mode!r} at {spp} spp)")
    with Renderer(dataclasses.replace(oracle.scene, **{effect: None}), "cpu", mesh=oracle.mesh) as plain:
        if spp > 1:
            return plain.render(cam, step, mode=mode, samples_per_pixel=spp).image, \
                renderer_grey(plain, mode, cam, step, spp, FLOAT64)
        q = plain.render(cam, step, mode=mode, truth=True)
        shift = mapping(mode, oracle.scene.cameras[cam].fx, q.truth.ref_uv, q.truth.mask)
        return q.image, np.where(q.truth.mask, renderer_grey(plain, mode, cam, step, 1, shift, q.truth), 0.0)


def renderer_motion(gl, oracle, mode: str, cam: int, step: int, spp: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """How far the GL renderer ``gl``'s image of camera ``cam`` at ``step`` under the scene's
    [exposure] (motion over the exposure, a rolling shutter; no other effect) may lie from the
    oracle renderer ``oracle``'s, in ``mode`` at ``spp`` (fast: 1), per pixel: (bound, ties).
    Both average the same sub-frames (:meth:`glsim.render.Renderer.sub_frames`: the states'
    nodes are made once in float64 for both), in float64, and round the mean to float32:

    - each sub-frame is a still render of its state (a rolling shutter's: of its row's
      one-row camera, the same rays as the row): off its ties GL's lies within :func:`grey` of
      the oracle's, its reference points within :func:`mapping` (at 1 spp from the oracle's
      sub-frame raster, else exact and q4's largest gradient, :func:`renderer_grey`); fast's
      takes the map's gradient from neighbouring pixels, which a one-row band lacks: a rolling
      shutter's row takes it from the oracle's map of the rows around it in the row's state
      (:func:`_row_fast_bound`);
    - the mean of differences is at most the mean of their bounds; the roundings of the two
      means m to float32 add u·(|m_GL| + |m_oracle|) ≤ u·(2|m_oracle| + bound) (u = 2^-24);
    - ties: the union of the sub-frames' (:func:`near_edges` within :func:`tie_px` of the
      state's edges through the row's camera; a quadratic mesh's curved edges: none claimed,
      both decide its coverage in float64, as in its still renders).
    """
    from glsim.effects import motion

    scene = oracle.scene
    others = [e for e in ("lighting", "optics", "psf", "vignetting", "noise") if getattr(scene, e) is not None]
    rows, _, taus = oracle.exposure_schedule(cam, step)
    if others or scene.exposure is None or (mode == "fast" and spp > 1):
        raise ValueError(f"renderer_motion: derived for [exposure] alone, fast at 1 sample per pixel "
                         f"(the scene has {others}, exposure {scene.exposure is not None}, mode {mode!r} at {spp} spp)")
    method, coeffs, M = _reference(oracle)
    camera, u = scene.cameras[cam], FLOAT32_ROUNDOFF
    radius = tie_px(mode, camera.fx, gl.backend.capabilities.subpixel_bits)
    W, H = camera.size
    total, mean, ties = np.zeros((H, W)), np.zeros((H, W)), np.zeros((H, W), bool)
    for row, _, nodes, out in oracle.sub_frames(cam, step, truth=spp == 1, mode=mode, samples_per_pixel=spp):
        band = camera if row is None else motion.row_band(camera, row)[0]
        at = slice(None) if row is None else slice(row, row + 1)
        mean[at] += out.image / len(taus)
        if spp == 1:
            h = band.height
            mask = out.samples["element"].reshape(h, W) >= 0
            ref_uv = out.samples["ref_uv"].reshape(h, W, 2)
            grad = sample_gradient(method, coeffs, ref_uv, mask)
            moved = (_row_fast_bound(oracle, camera, row, nodes) if mode == "fast" and row is not None
                     else mapping(mode, camera.fx, ref_uv, mask))
            total[at] += np.where(mask, grey(method, M, grad, moved), 0.0)
        else:
            total[at] += grey(method, M, gradient_max(method) * M, FLOAT64, spp)
        if not oracle.mesh.is_quadratic:
            ties[at] |= near_edges(band, nodes, oracle.mesh.quads, radius, spp, exact=mode == "exact")
    bound = total / len(taus)
    return bound + u * (2 * np.abs(mean) + bound), ties


def _row_fast_bound(oracle, camera, row: int, nodes: np.ndarray) -> np.ndarray:
    """:func:`fast_bound` of a rolling shutter's ``row`` of ``camera`` (1, W) with the nodes of
    its state (world mm): from the oracle's fast map of the rows around it (the band of
    :func:`glsim.effects.motion.row_band` ± 1 row, the same rays), so that its gradient has
    the row's neighbours above and below."""
    from glsim.backends.cpu import rasterize
    from glsim.effects.motion import row_band
    from glsim.imaging.view import make_view

    band, at = row_band(camera, row, 1)
    mesh = oracle.drawn_mesh
    r = rasterize(make_view(band, oracle.reference.camera, mesh.nodes, nodes, mesh.quads, warn=False), "fast")
    W, h = band.size
    field = r["ref_uv"].reshape(h, W, 2)
    return fast_bound(camera.fx, field, r["element"].reshape(h, W) >= 0)[at:at + 1]


def renderer_dof(oracle, mode: str, cam: int, step: int, sharp: np.ndarray, before,
                 spp: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """How far a GL renderer's depth-of-field image may lie from the oracle renderer ``oracle``'s
    of camera ``cam`` at ``step`` in ``mode`` at ``spp``, given the oracle's
    image before the blur ``sharp`` (H, W) and the bound ``before`` of GL's against it there.
    A pixel's depth is its sample's, or the mean of its covered samples' (dof.pixel_depth, from
    the oracle's samples: :func:`sample_truth`). Returns (bound, ties), per pixel (H, W): where
    a pixel's σ (= CoC/2 from its depth; the disk kernel's radius r is the same number) may be
    decided the other way — within its own error of the in-focus threshold or, Gaussian, of a
    window step R = ceil(3σ) (the disk's window ceil(r) only adds taps of weight 0) — it is a
    tie; elsewhere, first order in u:

    - the gathered source: a normalised average moves by at most its window's largest ``before``;
    - GL's scheme against the exact gather on the same source and σ: its rounding (:func:`blur`:
      the gather's, hybrid's, the disk's) and, for the Gaussian default expansion,
      dof.EXPANSION_TOL of the source's grey range;
    - σ's own error δσ: shaders/dof.glsl's CoC in float32 (:func:`coc`; at Z = D, where that
      relative error has no limit, the CoC's slope times D's rounding) and the depth GL reads —
      its samples' Z as float32 and their float32 mean ((n + 4)u|Z|), in fast also
      interpolated (|∂Z/∂uv|·:func:`fast_px`) — through |∂CoC/∂Z|; through the gather
      |∂out/∂σ| ≤ (2R²/σ³)·(the window's grey range); the disk's weights clamp(r + ½ − |d|, 0, 1)
      move by δr on their ramp only: |Δout| ≤ δr·(taps within r ± (½ + δr))/Σw·(the range).
    The separable scheme, inexact where σ varies, is not derived here."""
    import cv2

    from glsim.effects import dof

    optics, camera = oracle.scene.optics, oracle.scene.cameras[cam]
    scheme = dof.blur_scheme(optics)
    if scheme == "separable":
        raise ValueError("renderer_dof: the separable scheme is not derived here")
    u = FLOAT32_ROUNDOFF
    fine, truth = sample_truth(oracle, mode, cam, step, spp)
    z = np.zeros(truth.mask.shape)
    z[truth.mask] = _pixel_points(oracle, fine, step, truth, "renderer_dof")[3][:, 2]
    s = int(round(np.sqrt(spp)))
    Z = dof.pixel_depth(z, camera.height, camera.width, s)
    m = Z > 0
    dZ = (spp + 4) * u * np.abs(Z)   # the samples' float32 depths and their float32 mean
    if mode == "fast":
        dZ = dZ + per_pixel(Z[..., None], m) * fast_px(camera.fx)
    sigma = dof.blur_sigma(Z, optics)
    c = np.where(m, dof.coc_px(np.where(m, Z, 2 * optics.focal_length + 1.0), optics), 0.0)
    slope = np.where(m, dof.coc_slope(np.where(m, Z, 2 * optics.focal_length + 1.0), optics), 0.0)   # px/mm
    with np.errstate(divide="ignore", invalid="ignore"):
        own = c * coc(np.where(m, Z, 1.0), optics)   # relative to CoC; at Z = D exactly its limit: the slope·δD
    own = np.where(np.isfinite(own), own, slope * (f32_error(optics.focus_distance) + u * np.abs(Z)))
    dcoc = np.where(m, own + slope * dZ, 0.0)
    dsigma = dcoc / 2
    disk = scheme == "disk"
    R = dof.kernel_radius(sigma, "disk" if disk else "gaussian")
    threshold = getattr(optics, "coc_px", 1.0)
    step_tie = (sigma > 0) & (np.abs(3 * sigma - np.round(3 * sigma)) <= 3 * dsigma) & (not disk)   # R = ceil(3σ) changes
    ties = m & ((np.abs(c - threshold) <= dcoc) | step_tie)
    reach = int(R.max(initial=0))
    window = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    src = np.asarray(sharp, np.float64)
    spread = cv2.dilate(src, window) - cv2.erode(src, window)
    moved = cv2.dilate(np.asarray(before, np.float64), window)
    M, F = float(np.abs(src).max()), float(np.ptp(src))
    scheme_err = blur(scheme if scheme in ("hybrid", "disk") else "gather", sigma, M) \
        + (dof.EXPANSION_TOL * F if scheme == "expansion" else 0.0)
    if disk:
        per_sigma = disk_ramp(sigma, dsigma)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            per_sigma = np.where(sigma > 0, 2 * R.astype(np.float64) ** 2 / sigma ** 3, 0.0)   # |∂out/∂σ| / range
    bound = np.where(sigma > 0, moved + scheme_err + per_sigma * spread * dsigma, before)
    return bound, ties


def renderer_noise(oracle, cam: int, step: int, image: np.ndarray, before) -> np.ndarray:
    """Per pixel (H, W), how far a GL renderer's noisy image may lie from the oracle renderer
    ``oracle``'s of camera ``cam`` at ``step``, given the oracle's image before the noise
    ``image`` (H, W) and the bound ``before`` of GL's against it there (:func:`renderer_grey`,
    :func:`renderer_lit`): I + σ(I)·z moves by ΔI and σ(I ± ΔI) − σ(I) (σ is monotone in I) times
    |z|, plus the noise pass's own float32 error on the same I (:func:`noise`: the normal
    field's, σ's and the sum's)."""
    from glsim.effects import noise as nz

    scene, camera = oracle.scene, oracle.scene.cameras[cam]
    params, bits = scene.noise, camera.bit_depth
    table = nz.load_variance_table(scene.resolve(params.variance_file), bits) if params.model == "heteroscedastic" else None
    z, dz = normal_field(nz.stream_seed(scene.seed, cam, step), image.shape)
    I = np.asarray(image, np.float64)
    sigma = nz.noise_sigma(I, params, bits, table)
    moved = np.maximum(*(np.abs(nz.noise_sigma(I + k * before, params, bits, table) - sigma) for k in (1, -1)))
    return before + moved * np.abs(z) + noise(I, z, dz, sigma, params, bits, table)
