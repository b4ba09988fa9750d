"""The CPU backend: a vectorised numpy float64 rasterizer, the reference oracle of the GL path.

For every sample it finds the candidate elements from pixel boxes, maps the sample into each
(mode ``fast``: perspective-correct triangles; ``q4``: the paper's Gauss–Newton inverse in the
projected element, tolerance 1e-12; ``exact``: the pixel's undistorted ray intersected with the
bilinear patch), keeps the nearest hit (depth test) and interpolates the reference image there.
"""
from __future__ import annotations

import numpy as np

from glsim.scene import bilinear as bl
from glsim.scene import quadratic as qd
from glsim.imaging import interp
from glsim.imaging.reference import require_dots
from glsim.scene.camera import pixel_grid, pixel_to_normalized, project_camera_frame, undistort
from glsim.backends.contract import Capabilities, Raster, Request
from glsim.imaging.quadview import make_quad_view
from glsim.imaging.truth import polish
from glsim.imaging.view import View, make_view, warn_dropped

CHUNK = 1 << 21  # candidate (element, sample) pairs evaluated at once


def _boxes(view: View, mode: str, s: int, aperture: float = 1.0) -> np.ndarray:
    """Inclusive sample-index boxes [i0, j0, i1, j1] per element on the s-times grid (with
    ``aperture`` < 1 every sample of the pixels whose squares the element's box meets)."""
    W, H = view.camera.size
    if mode == "exact":
        b = view.bbox
        box = np.stack([b[:, 0] * s, b[:, 1] * s, b[:, 2] * s + s - 1, b[:, 3] * s + s - 1], 1)
        box[(b[:, 2] < b[:, 0]) | (b[:, 3] < b[:, 1])] = (0, 0, -1, -1)
        return box
    lo = view.uv.min(axis=1)
    hi = view.uv.max(axis=1)
    if aperture != 1.0:   # pixel c's samples lie inside [c − ½, c + ½]
        box = np.concatenate([np.ceil(lo - 0.5) * s, np.floor(hi + 0.5) * s + s - 1], 1)
    else:
        box = np.concatenate([np.ceil((lo + 0.5) * s - 0.5), np.floor((hi + 0.5) * s - 0.5)], 1)
    box = np.clip(box, -1, [W * s, H * s, W * s - 1, H * s - 1]).astype(np.int64)
    box[:, :2] = np.maximum(box[:, :2], 0)
    box[~view.projectable] = (0, 0, -1, -1)
    return box


def _candidates(box: np.ndarray, width: int):
    """Yield (element, flat sample index) arrays covering every box, in chunks."""
    nx = np.maximum(box[:, 2] - box[:, 0] + 1, 0)
    ny = np.maximum(box[:, 3] - box[:, 1] + 1, 0)
    count = nx * ny
    elems = np.flatnonzero(count)
    start = 0
    while start < len(elems):
        csum = np.cumsum(count[elems[start:]])
        stop = start + max(1, int(np.searchsorted(csum, CHUNK, side="right")))
        sel = elems[start:stop]
        n = count[sel]
        e = np.repeat(sel, n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        i = box[e, 0] + local % nx[e]
        j = box[e, 1] + local // nx[e]
        yield e, j * width + i
        start = stop


def _fast(view: View, e, q):
    """Two perspective-correct triangles (0,1,2), (0,2,3) per quad, vertices distorted."""
    uv = view.uv[e]
    z = view.Xd[e, :, 2]
    corner_xe = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    out_xe = np.zeros(q.shape)
    out_ref = np.zeros(q.shape)
    depth = np.full(len(q), np.inf)
    ok = np.zeros(len(q), bool)
    for tri in bl.FAST_TRIANGLES:
        lam, hit = bl.triangle_barycentric(uv, q, tri, ok)   # coverage: the shared tie rule
        w = lam / z[:, tri]
        w /= np.where(hit, w.sum(-1), 1.0)[:, None]
        out_ref = np.where(hit[:, None], np.einsum("nk,nkd->nd", w, view.ref_uv[e][:, tri]), out_ref)
        out_xe = np.where(hit[:, None], w @ corner_xe[list(tri)], out_xe)
        depth = np.where(hit, 1.0 / np.where(hit, (lam / z[:, tri]).sum(-1), 1.0), depth)
        ok |= hit
    return ok, depth, out_xe[:, 0], out_xe[:, 1], out_ref


def _q4(view: View, e, q, tol=1e-12):
    p = view.uv[e]
    xi, eta, conv = bl.invert_newton(p, q, tol=tol, max_iter=50)
    E, m = bl.edge_functions_2d(p, q)
    ok = conv & bl.owned(xi, eta, E, m, bl.orientation_2d(p, xi, eta))  # the shared tie rule
    depth = bl.bilinear(view.Xd[e, :, 2:], xi, eta)[:, 0]
    return ok, depth, xi, eta, bl.bilinear(view.ref_uv[e], xi, eta)


def _exact(view: View, e, q, xn, ray_ok):
    cam = view.camera   # a pinhole camera decides ties from the samples' pixel points (exact)
    pixel = None if np.any(cam.distortion.coeffs) else (q, cam.intrinsics)
    xi, eta, depth, ok = bl.intersect_ray_patch(view.Xd[e], xn, pixel)
    ref_uv, ref_ok = project_camera_frame(bl.bilinear(view.Xr[e], xi, eta), view.ref_camera)
    # a point the reference camera cannot see counts as outside the reference image (NaN)
    return ok & ray_ok, depth, xi, eta, np.where(ref_ok[:, None], ref_uv, np.nan)


def _nearest(camera, ref_camera, box: np.ndarray, s: int, rays: bool, map_chunk, aperture: float = 1.0) -> dict:
    """The nearest element per sample on the s×s-per-pixel grid, over the candidates of the
    elements' sample boxes ``box`` (chunks come in ascending element order, so exact depth
    ties go to the lower element index). ``map_chunk(e, idx, q, xn, xn_ok)`` maps the samples
    ``idx`` (grid points ``q``; their undistorted rays ``xn`` when ``rays``) into the elements
    ``e``: ``(ok, depth, xi, eta, ref_uv)``; ``aperture``: :func:`pixel_grid`'s."""
    W, H = camera.size
    grid = pixel_grid(camera, s * s, aperture).reshape(-1, 2)
    n = len(grid)
    best = {"element": np.full(n, -1, np.int64), "depth": np.full(n, np.inf),
            "xi": np.zeros(n), "eta": np.zeros(n), "ref_uv": np.zeros((n, 2))}
    if rays:  # normalized undistorted coordinates as the GL ray map stores them (no normalisation)
        xn, xn_ok = undistort(pixel_to_normalized(grid, camera.intrinsics), camera.distortion.coeffs)
    rw, rh = ref_camera.size
    dropped = np.zeros(n, bool)  # hit the specimen, but the reference point is outside the image
    for e, idx in _candidates(box, W * s):
        ok, depth, xi, eta, ref = map_chunk(e, idx, grid[idx], xn[idx] if rays else None,
                                            xn_ok[idx] if rays else None)
        inside_ref = (ref[:, 0] >= -0.5) & (ref[:, 0] <= rw - 0.5) & (ref[:, 1] >= -0.5) & (ref[:, 1] <= rh - 0.5)
        dropped[idx[ok & ~inside_ref]] = True
        ok &= inside_ref
        k = np.flatnonzero(ok)
        order = k[np.lexsort((e[k], depth[k], idx[k]))]
        first = order[np.unique(idx[order], return_index=True)[1]]
        win = first[depth[first] < best["depth"][idx[first]]]
        t = idx[win]
        best["element"][t] = e[win]
        best["depth"][t] = depth[win]
        best["xi"][t] = xi[win]
        best["eta"][t] = eta[win]
        best["ref_uv"][t] = ref[win]
    best["dropped"] = dropped & (best["element"] < 0)
    return best


def rasterize(view: View, mode: str, s: int = 1, aperture: float = 1.0) -> dict:
    """Nearest element per sample on the s×s-per-pixel grid (offsets scaled by ``aperture``,
    √ of the sensor's fill factor: :func:`glsim.scene.camera.pixel_grid`).

    Returns flat arrays over the (H·s)·(W·s) samples: ``element`` (−1 where none), ``xi``,
    ``eta``, ``ref_uv`` (reference-image px), ``depth`` (camera Z, mm) and ``dropped``
    (samples that hit an element whose reference point lies outside the reference image).
    """
    def map_chunk(e, idx, q, xn, xn_ok):
        if mode == "fast":
            return _fast(view, e, q)
        if mode == "q4":
            return _q4(view, e, q)
        return _exact(view, e, q, xn, xn_ok)

    return _nearest(view.camera, view.ref_camera, _boxes(view, mode, s, aperture), s, mode == "exact", map_chunk,
                    aperture)


def rasterize_quadratic(view, mode: str, s: int = 1, aperture: float = 1.0) -> dict:
    """:func:`rasterize` for quadratic elements (a :class:`~glsim.imaging.quadview.QuadView`),
    modes ``exact`` (the sample's ray against the curved patch,
    :func:`glsim.scene.quadratic.intersect_ray`) and ``q4`` (the paper's inverse mapping
    with the element's own 9-node shape functions in the image, :func:`glsim.scene.quadratic.invert`
    from the 2×2 sub-quad start; reference point = the same shape functions over the nodes'
    reference-image projections). ``xi``, ``eta`` are the patch's (ξ, η). A sample on an edge
    shared by two patches (|ξ| or |η| within 1e-9 of 1 in both) goes to the nearer, then to the
    lower element index: no gaps, no double cover."""
    if mode not in ("exact", "q4"):
        raise ValueError(f"rasterize_quadratic draws modes exact and q4, not {mode!r}")
    b = view.bbox
    box = np.stack([b[:, 0] * s, b[:, 1] * s, b[:, 2] * s + s - 1, b[:, 3] * s + s - 1], 1)
    box[(b[:, 2] < b[:, 0]) | (b[:, 3] < b[:, 1])] = (0, 0, -1, -1)

    def map_chunk(e, idx, q, xn, xn_ok):
        if mode == "q4":
            Z = view.Pd[e, :, 2:]
            xi, eta, ok = qd.invert(view.uv[e], q, lambda i, x, y: qd.evaluate(Z[i], x, y)[:, 0])
            return ok, qd.evaluate(Z, xi, eta)[:, 0], xi, eta, qd.evaluate(view.ref_uv[e], xi, eta)
        xi, eta, depth, ok = qd.intersect_ray(view.Pd[e], xn)
        ref, ref_ok = project_camera_frame(qd.evaluate(view.Pr[e], xi, eta), view.ref_camera)
        return ok & xn_ok, depth, xi, eta, np.where(ref_ok[:, None], ref, np.nan)

    return _nearest(view.camera, view.ref_camera, box, s, mode == "exact", map_chunk, aperture)


def _shade(view, r: dict, hit: np.ndarray, grey: np.ndarray, fx) -> np.ndarray:
    """Phong lighting per sample (surface point and interpolated normal), combined with grey.
    For quadratic patches (a QuadView): the point on the curved patch, the normal interpolated
    over the linear piece holding it (``fx.normals`` are the pieces' corner normals)."""
    from glsim.effects import lighting as shade

    e, xi, eta = r["element"][hit], r["xi"][hit], r["eta"][hit]
    if hasattr(view, "Pd"):
        X = qd.evaluate(view.Pd[e], xi, eta)
        piece, xs, ys = qd.piece_of(e, xi, eta, view.pieces)
        N = bl.bilinear(fx.normals[piece], xs, ys)
    else:
        X = bl.bilinear(view.Xd[e], xi, eta)
        N = bl.bilinear(fx.normals[e], xi, eta)
    norm = np.linalg.norm(N, axis=-1, keepdims=True)
    N = np.divide(N, norm, out=np.zeros_like(N), where=norm > 0)
    lit = fx.lighting
    I = shade.phong(X, N, fx.lights, lit.ambient, lit.diffuse, lit.specular, lit.shininess)
    return shade.combine(grey, I, lit.combine)


def _box(a: np.ndarray, H: int, W: int, s: int) -> np.ndarray:
    return a.reshape(H, s, W, s).mean(axis=(1, 3))


def render_view(view: View, sample, opts, truth: bool, fx=None, raster=None, polished: bool = True):
    """Image (H, W) float32, the pixel-centre raster of :func:`rasterize` if ``truth``, and
    the list of stages run. ``sample(uv)`` gives the reference grey at reference-image
    coordinates; ``opts`` is the scene's Render; ``fx`` the Effects; ``raster`` replaces
    :func:`rasterize` (:func:`rasterize_quadratic` for a QuadView); ``polished`` False leaves
    mode fast's (ξ, η) as its triangles give them (Request.polish)."""
    raster = raster or rasterize
    from glsim.effects import Effects

    fx = fx or Effects()
    W, H = view.camera.size
    s = opts.supersampling
    stages = ["raster", "interpolate"]
    r = raster(view, opts.mode, s, fx.aperture)
    warn_dropped(view.camera, int(r["dropped"].sum()), s)
    hit = r["element"] >= 0
    grey = np.full(len(hit), float(opts.background))
    idx = np.flatnonzero(hit)
    for k in range(0, len(idx), CHUNK):  # bounded memory at high supersampling
        grey[idx[k:k + CHUNK]] = sample(r["ref_uv"][idx[k:k + CHUNK]])
    if fx.lighting is not None:
        grey[hit] = _shade(view, r, hit, grey[hit], fx)
        stages.append("light")
    image = _box(grey, H, W, s) if s > 1 else grey.reshape(H, W)
    if s > 1:
        stages.append("downsample")
    if fx.blur:
        from glsim.effects import dof as blur

        depth = blur.pixel_depth(np.where(hit, r["depth"], 0.0), H, W, s)
        if fx.optics.kernel == "disk":
            image = blur.blur_disk(image, blur.blur_sigma(depth, fx.optics))
        else:
            image = blur.blur_exact(image, blur.blur_sigma(depth, fx.optics))
        stages.append("blur")
    image = camera_stages(image, fx, stages)
    if fx.noise is not None:
        from glsim.effects import noise

        image = noise.add_noise(image, fx.noise, fx.bit_depth, fx.noise_seed, fx.variance)
        stages.append("noise")
    if not truth:
        return image, None, stages
    r = r if s == 1 else raster(view, opts.mode, 1)
    if opts.mode == "fast" and polished:  # truth at the material point that coloured the pixel (exact, q4: float64 already)
        r = polish(view, "fast", r)
    return image, r, stages


def camera_stages(image: np.ndarray, fx, stages: list) -> np.ndarray:
    """Vignetting and the lens PSF on the float64 irradiance, then (float32) the fixed-pattern
    noise (docs/camera.md); the names of those run go to ``stages``."""
    if fx.vignette is not None:
        image = image * fx.vignette
        stages.append("vignette")
    if fx.psf is not None:
        from glsim.effects import psf

        image = psf.apply(image, fx.psf)
        stages.append("psf")
    image = image.astype(np.float32)
    if fx.fixed_pattern:
        from glsim.effects import noise

        image = noise.fixed_pattern(image, fx.sensor.prnu, fx.sensor.dsnu, fx.bit_depth, fx.fpn_seed).astype(np.float32)
        stages.append("fixed_pattern")
    return image


class CPUBackend:
    """backend="cpu": float64 numpy, the oracle, behind the backend contract
    (:mod:`glsim.backends.contract`): it builds the numpy view of a request (every element's
    corners, projections and boxes; the curved patches' for quadratic elements) and renders it."""
    name = "cpu"
    capabilities = Capabilities(device_geometry=False, float64=True, passes=False)

    def __init__(self, reference_image: np.ndarray, dots=None):
        self._image = reference_image
        self._dots = dots
        self._samplers: dict = {}

    def sampler(self, interpolation: str):
        """uv → reference grey: the interpolated image, or the exact procedural speckle."""
        if interpolation not in self._samplers:
            if interpolation == "procedural":
                from glsim.scene import speckle

                dots = require_dots(self._dots)
                grid = speckle.dot_grid(dots)
                self._samplers[interpolation] = lambda uv: speckle.evaluate(dots, uv, grid)
            else:
                coeffs = interp.prepare(self._image, interpolation, np.float64)
                self._samplers[interpolation] = lambda uv: interp.sample(coeffs, uv, interpolation)
        return self._samplers[interpolation]

    def render(self, request: Request) -> Raster:
        v, opts, c = request.view, request.options, request.curved
        if c is not None:
            m = c.mesh
            view = make_quad_view(v.camera, v.ref_camera, m.nodes, c.deformed(), m.patches, m.element_labels,
                                  pieces=c.pieces, pieces_def=v.step_geo.deformed, mode=opts.mode)
        else:
            mesh = v.mesh_geo.mesh
            view = make_view(v.camera, v.ref_camera, mesh.nodes, v.step_geo.deformed, mesh.quads, mesh.element_labels)
        image, r, stages = render_view(view, self.sampler(opts.interpolation), opts, request.truth, request.effects,
                                       rasterize_quadratic if c is not None else None, request.polish)
        return Raster(image, r, tuple(stages))

    def submit(self, request: Request) -> Raster:
        """The oracle works synchronously: the Raster itself is the token."""
        return self.render(request)

    @staticmethod
    def collect(token: Raster) -> Raster:
        return token

    def close(self) -> None:
        self._samplers.clear()
