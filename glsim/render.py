"""The one entry point: render a camera at a load step with backend "gl" or "cpu".

    with Renderer(scene) as r:
        res = r.render("cam0", step=1, truth=True)
        res.image, res.truth.ref_uv

Both backends take the same scene and return the same :class:`Result`.

Quadratic meshes (``Mesh.patches``, :mod:`glsim.scene.quadratic`): mode ``fast`` draws the
mesh cut into QUADRATIC_FAST_PIECES × QUADRATIC_FAST_PIECES bilinear pieces per element with
either backend (``Renderer.pieces``); ``exact`` and ``q4`` map every sample on the curved
patch: the CPU oracle with :func:`glsim.backends.cpu.rasterize_quadratic`, GL over the same
pieces' covers and candidate lists with Newton on the patch's 9 nodes (shaders/quadratic.glsl).
Truth always reports the element's own (ξ, η) (for T6 those of the collapsed patch).
"""
from __future__ import annotations

import functools
from collections.abc import Callable
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from glsim.errors import RenderWarning, SceneError
from glsim.limits import check_gl_target, check_image_size, check_memory
from glsim.scene import quadratic as qd
from glsim.scene.bilinear import bilinear
from glsim.scene.camera import Camera, pixel_to_normalized, project_camera_frame, to_camera, undistort
from glsim.effects import prepare as prepare_effects
from glsim.stages.geometry import MeshGeometry, ViewSpec
from glsim.io.truth import Truth, pixel_positions
from glsim.stages.quadview import PatchData, chord_error_bound, fast_local_coords as quadratic_fast_coords, \
    make_quad_view, q4_image_bound
from glsim.stages.view import NEAR_MM, View, _labels, coverage, make_view, warn_unseen
from glsim.backends import make_backend
from glsim.io.fe import specimen_mesh
from glsim.stages.reference import make_reference
from glsim.scene import Render, Scene

QUADRATIC_FAST_PIECES = 4   # fast mode: n × n linear pieces per quadratic element (docs/quadratic.md)


@dataclass(frozen=True, eq=False)
class Result:
    """One rendered image: float32 (H, W) grey levels in [0, 1] of full scale."""
    image: np.ndarray
    camera: Camera
    step: int
    backend: str
    options: Render
    seconds: float
    truth: Truth | None = None
    stages: tuple[str, ...] = ()      # the pipeline stages / GL passes that ran
    specimen: Callable[[], np.ndarray] | None = field(default=None, repr=False)  # makes ``coverage`` when first asked

    @functools.cached_property
    def coverage(self) -> np.ndarray:
        """(H, W) bool: the specimen's pixels (:func:`glsim.stages.view.coverage`), made on first
        access (a CPU projection of every element: not part of the render's cost)."""
        W, H = self.camera.size
        return self.specimen() if self.specimen is not None else np.zeros((H, W), bool)

    @property
    def covered(self) -> float:
        """Fraction of the image's pixels on the specimen."""
        return float(self.coverage.mean()) if self.coverage.size else 0.0

    @functools.cached_property
    def saturated(self) -> float:
        """Fraction of the specimen's pixels below 0 or above full scale (clipped when quantised)."""
        return _saturated(self.image, self.coverage)


class Renderer:
    """Renders one scene with one backend; holds the mesh, reference and backend resources."""

    def __init__(self, scene: Scene, backend: str | None = None, ctx=None, mesh=None, reference=None,
                 pieces: int | None = None):
        """``mesh`` / ``reference`` replace the scene's specimen mesh and reference image
        (e.g. a calibration target made in code); ``ctx`` shares a GL context; ``pieces``: for a
        quadratic mesh, the linear pieces per element side (default QUADRATIC_FAST_PIECES):
        the fast mode's accuracy (its error falls as 1/pieces², docs/quadratic.md)."""
        self.scene = scene
        self.mesh = mesh if mesh is not None else specimen_mesh(scene)
        self._pieces = None
        self._n_pieces = QUADRATIC_FAST_PIECES if pieces is None else int(pieces)
        if self._n_pieces < 1:
            raise SceneError("pieces", f"{pieces!r} is not a positive integer", "give 1 or more (default 4)")
        self.reference = reference if reference is not None else make_reference(scene, self.drawn_mesh)
        self.backend_name = backend or scene.render.backend
        self.backend = make_backend(self.backend_name, self.reference, ctx)
        self._geometry: MeshGeometry | None = None
        if self._gl_max:   # the reference image is one texture
            H, W = self.reference.image.shape
            check_image_size("speckle", W, H, "the reference image", "give a smaller image, or a smaller "
                             "speckle.oversample", self._gl_max)

    @functools.cached_property
    def _gl_max(self) -> int | None:
        """The GL context's largest texture and render-buffer side (px); None for the CPU oracle."""
        info = getattr(self.backend, "ctx", None) and self.backend.ctx.info
        return min(info["GL_MAX_TEXTURE_SIZE"], info["GL_MAX_RENDERBUFFER_SIZE"]) if info else None

    def check_size(self, camera: int | str, truth: bool = False, opts: Render | None = None) -> None:
        """SceneError if rendering ``camera`` with ``opts`` (default: the scene's [render]) needs a GL
        target over this context's limit or more memory than this process may use (:mod:`glsim.limits`)."""
        cam = self.scene.camera(camera)
        spp = (opts or self.scene.render).samples_per_pixel
        if self._gl_max:
            check_gl_target("render.samples_per_pixel", cam.size, spp, self._gl_max)
        check_memory(f"cameras[{self.scene.cameras.index(cam)}].size", cam.size, spp, truth)

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self.backend.close()

    @property
    def pieces(self) -> qd.Pieces | None:
        """For a quadratic mesh, its linear pieces (what the fast mode draws); None otherwise."""
        if self.mesh.is_quadratic and self._pieces is None:
            self._pieces = qd.linearize(self.mesh, self._n_pieces)
        return self._pieces

    @property
    def drawn_mesh(self):
        """The linear mesh the linear paths draw: the mesh, or a quadratic mesh's pieces."""
        return self.pieces.mesh if self.mesh.is_quadratic else self.mesh

    def view(self, camera: int | str, step: int, deformed: np.ndarray | None = None) -> View:
        """The per-element geometry of ``camera`` at ``step`` (``deformed``: its nodes, if known)
        as a full numpy :class:`View` (O(elements); what the CPU oracle renders), with warnings.
        For a quadratic mesh: of its linear pieces (``deformed`` then the pieces' nodes)."""
        cam = self.scene.camera(camera)
        mesh = self.drawn_mesh
        nodes = mesh.deformed(step) if deformed is None else deformed
        return make_view(cam, self.reference.camera, mesh.nodes, nodes, mesh.quads, mesh.element_labels)

    @property
    def geometry(self) -> MeshGeometry:
        """The mesh as the GL path holds it: per renderer, per load step (cached), per view O(1)
        (of the linear pieces for a quadratic mesh)."""
        if self._geometry is None:
            self._geometry = MeshGeometry(self.drawn_mesh, self.reference.camera)
        return self._geometry

    def render(self, camera: int | str = 0, step: int = 0, truth: bool = False, **options) -> Result:
        """Render one image. ``options`` override the scene's [render] table (mode, …).

        GL: the view is a :class:`ViewSpec` (the camera's transform; the per-element work runs
        on the GPU from the mesh uploaded once and the step's nodes uploaded once); the CPU
        oracle gets the full numpy :class:`View`."""
        opts = self.scene.replace(render=options).render if options else self.scene.render
        self.check_size(camera, truth, opts)
        t0 = time.perf_counter()
        cam = self.scene.camera(camera)
        curved = self.mesh.is_quadratic and opts.mode != "fast"
        if curved and self.backend_name != "gl":
            return self._render_quadratic(cam, step, truth, opts, t0)
        patches = None
        if self.backend_name == "gl":
            view = self.geometry.view(cam, step)
            deformed = view.step_geo.deformed
            depths = view.corner_depths() if self.scene.optics is not None else np.empty(0)
            if curved:
                patches = self._patch_data(view, step, opts)
        else:
            deformed = self.drawn_mesh.deformed(step)
            view = self.view(camera, step, deformed)
            depths = view.Xd[..., 2]
        fx = prepare_effects(self.scene, deformed, self.drawn_mesh.quads, cam, self.scene.cameras.index(cam), step,
                             depths, normals=self.backend_name != "gl")
        if patches is not None:
            image, raster, stages = self.backend.render_view(view, opts, truth, fx, patches=patches)
        else:
            image, raster, stages = self.backend.render_view(view, opts, truth, fx)
        seconds = time.perf_counter() - t0
        if truth and patches is not None:
            tr = self._quadratic_truth(self._pieces_to_patches(raster, cam, step, opts.mode), step, cam)
        elif truth and self.mesh.is_quadratic:
            tr = self._quadratic_truth(self._fast_to_patches(raster), step, cam)
        else:
            tr = self._truth(view.camera.size, deformed, raster) if truth else None
        return Result(image=image, camera=view.camera, step=step, backend=self.backend_name,
                      options=opts, seconds=seconds, truth=tr, stages=tuple(stages),
                      specimen=self._specimen(cam, deformed, self.drawn_mesh.quads))

    def _patch_data(self, view: ViewSpec, step: int, opts: Render) -> PatchData:
        """The GL backend's quadratic payload for ``view`` (its elements are the pieces): the
        step's patch points (cached per step), the reference data (once), the chord bound."""
        cache = self.__dict__.setdefault("_patch_cache", {})
        if "ref" not in cache:
            ref_cam = self.reference.camera
            xr = qd.patch_points(self.mesh.patches, to_camera(self.mesh.nodes, ref_cam))
            uv, _ = project_camera_frame(xr, ref_cam)
            cache["ref"] = (xr, uv)
        if cache.get("step", (None,))[0] != step:
            P = qd.patch_points(self.mesh.patches, self.mesh.deformed(step))
            folded = np.flatnonzero(qd.folded(P))
            cache["step"] = (step, P - self.geometry.origin, chord_error_bound(P, self.pieces.n), folded)
        _, local, chord_mm, folded = cache["step"]
        if folded.size:
            warnings.warn(f"camera {view.camera.name}: elements {_labels(folded, self.mesh.element_labels)} are "
                          "folded (the surface normal reverses inside the element: a mid-side node too far from its "
                          "edge's middle?); their pixels stay finite (the nearest root is drawn); check the mesh",
                          RenderWarning, stacklevel=4)
        z_near = max(float(view.corner_depths().min()), NEAR_MM)
        f = float(max(view.camera.intrinsics[0], view.camera.intrinsics[1]))
        sag_px = chord_mm * f / z_near
        if opts.mode == "q4":   # the q4 image map strays from the projected pieces: O(elements) per view
            P_cam = to_camera(local + self.geometry.origin, view.camera)
            sag_px = max(sag_px, q4_image_bound(P_cam, view.camera, self.pieces.n))
        xr, uv = cache["ref"]
        return PatchData(pieces=self.pieces.n, local=local, ref_xr=xr, ref_uv=uv,
                         extra_sag_px=1.5 * sag_px, token=(id(self), step))

    def _pieces_to_patches(self, raster: dict, cam: Camera, step: int, mode: str) -> dict:
        """A GL exact / q4 raster of the pieces → the patches: the piece's patch as element; the
        patch's (ξ, η) GL found, polished in float64 by :func:`glsim.scene.quadratic.newton`
        (on the pixel's ray, or in the image for q4; kept where that does not converge)."""
        r = dict(raster)
        hit = np.flatnonzero(r["element"] >= 0)
        e = self.pieces.parent[r["element"][hit]]
        W, _ = cam.size
        q = np.column_stack([hit % W, hit // W]).astype(np.float64)
        P = qd.patch_points(self.mesh.patches[e], to_camera(self.mesh.deformed(step), cam)) if hit.size else \
            np.zeros((0, 9, 3))
        if mode == "exact":
            xn, _ = undistort(pixel_to_normalized(q, cam.intrinsics), cam.distortion.coeffs)
            p2, target = P[..., :2] - xn[:, None, :] * P[..., 2:3], np.zeros_like(q)
        else:
            p2, target = project_camera_frame(P, cam)[0], q
        xi0, eta0 = r["xi"][hit], r["eta"][hit]
        xi, eta, ok = qd.newton(p2, target, xi0, eta0, qd.patch_size(p2))
        r["element"], r["xi"], r["eta"] = r["element"].copy(), r["xi"].copy(), r["eta"].copy()
        r["element"][hit] = e
        r["xi"][hit], r["eta"][hit] = np.where(ok, xi, xi0), np.where(ok, eta, eta0)
        return r

    @staticmethod
    def _specimen(cam: Camera, deformed: np.ndarray, quads: np.ndarray) -> Callable[[], np.ndarray]:
        """Warns when ``cam`` sees none of the specimen (RenderWarning, saying why); returns what
        makes its pixel mask on demand."""
        warn_unseen(cam, deformed, quads, stacklevel=5)
        return lambda: coverage(cam, deformed, quads)

    def _render_quadratic(self, cam: Camera, step: int, truth: bool, opts: Render, t0: float) -> Result:
        """exact / q4 of a quadratic mesh: the CPU oracle on the curved patches (lit with the
        point on the patch and the normals of its linear pieces, as GL)."""
        pieces = self.pieces
        view = make_quad_view(cam, self.reference.camera, self.mesh.nodes, self.mesh.deformed(step), self.mesh.patches,
                              self.mesh.element_labels, pieces=pieces, pieces_def=pieces.mesh.deformed(step),
                              mode=opts.mode)
        fx = prepare_effects(self.scene, pieces.mesh.deformed(step), pieces.mesh.quads, cam,
                             self.scene.cameras.index(cam), step, view.Pd[..., 2])
        image, raster, stages = self.backend.render_quadratic_view(view, opts, truth, fx)
        seconds = time.perf_counter() - t0
        tr = self._quadratic_truth(raster, step, cam) if truth else None
        return Result(image=image, camera=cam, step=step, backend=self.backend_name, options=opts, seconds=seconds,
                      truth=tr, stages=tuple(stages),
                      specimen=self._specimen(cam, pieces.mesh.deformed(step), pieces.mesh.quads))

    def _fast_to_patches(self, raster: dict) -> dict:
        """A fast-mode raster of the pieces → the patches: element and (ξ, η) of the parent,
        then (as for linear elements) the material point the reference camera sees at the
        sample's reference point, by Newton on the curved undeformed patch."""
        r = dict(raster)
        hit = np.flatnonzero(r["element"] >= 0)
        piece = r["element"][hit]
        e, xi, eta = self.pieces.to_parent(piece, r["xi"][hit], r["eta"][hit])
        ref_cam = self.reference.camera
        Pr = qd.patch_points(self.mesh.patches[e], to_camera(self.mesh.nodes, ref_cam)) if hit.size else \
            np.zeros((0, 9, 3))
        xi, eta = quadratic_fast_coords(ref_cam, Pr, r["ref_uv"][hit], xi, eta)
        r["element"] = r["element"].copy()
        r["xi"], r["eta"] = r["xi"].copy(), r["eta"].copy()
        r["element"][hit], r["xi"][hit], r["eta"][hit] = e, xi, eta
        return r

    def _quadratic_truth(self, raster: dict, step: int, cam: Camera) -> Truth:
        """Truth maps of a quadratic mesh from a raster of its patches (element, ξ, η, ref_uv):
        positions by the patches' own shape functions."""
        return self._truth(cam.size, self.mesh.deformed(step), raster, evaluate=self._patch_positions)

    def _patch_positions(self, nodes: np.ndarray, elements: np.ndarray, xi, eta) -> np.ndarray:
        return qd.evaluate(qd.patch_points(self.mesh.patches[elements], nodes), xi, eta)

    def _truth(self, size, deformed: np.ndarray, raster: dict, evaluate=None) -> Truth:
        W, H = size
        elem = raster["element"].reshape(H, W)
        mask = elem >= 0
        xi = np.where(mask, raster["xi"].reshape(H, W), np.nan)
        eta = np.where(mask, raster["eta"].reshape(H, W), np.nan)
        ref = np.where(mask[..., None], raster["ref_uv"].reshape(H, W, 2), np.nan)
        cam1, nodes, quads = self.scene.cameras[0], self.mesh.nodes, self.mesh.quads
        evaluate = evaluate or (lambda nodes, e, x, y: bilinear(nodes[quads[e]], x, y))
        e, x, y = elem[mask], xi[mask], eta[mask]
        return Truth(mask=mask, element=elem, xi=xi, eta=eta, ref_uv=ref,
                     positions=pixel_positions(mask, lambda: (to_camera(evaluate(nodes, e, x, y), cam1),
                                                              to_camera(evaluate(deformed, e, x, y), cam1))))


def _saturated(image: np.ndarray, covered: np.ndarray) -> float:
    """Fraction of the specimen's pixels (``covered``) below 0 or above full scale; the background
    is not counted (the extremes first: most images have none)."""
    n = np.count_nonzero(covered)
    if n == 0 or (image.min() >= 0 and image.max() <= 1):
        return 0.0
    return float(np.count_nonzero(((image < 0) | (image > 1)) & covered) / n)


def render(scene: Scene, camera: int | str = 0, step: int = 0, backend: str | None = None,
           truth: bool = False, **options) -> Result:
    """Render one image of ``scene`` (convenience wrapper around :class:`Renderer`)."""
    with Renderer(scene, backend) as r:
        return r.render(camera, step, truth, **options)
