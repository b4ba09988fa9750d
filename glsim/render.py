"""The one entry point: render a camera at a load step with backend "gl" or "cpu".

    with Renderer(scene) as r:
        res = r.render("cam0", step=1, truth=True)
        res.image, res.truth.ref_uv

Both backends take the same scene and return the same :class:`Result`.

Quadratic meshes (``Mesh.patches``, :mod:`glsim.scene.quadratic`): mode ``fast`` draws the
mesh cut into n × n bilinear pieces per element (``[render] pieces``, default 4) with either
backend (``Renderer.pieces``); ``exact`` and ``q4`` map every sample on the curved
patch: the CPU oracle with :func:`glsim.backends.cpu.rasterize_quadratic`, GL over the same
pieces' covers and candidate lists with Newton on the patch's 9 nodes (shaders/quadratic.glsl).
Truth always reports the element's own (ξ, η) (for T6 those of the collapsed patch).
"""
from __future__ import annotations

import dataclasses
import collections
import functools
import math
from collections.abc import Callable, Iterable, Iterator, Mapping
import time
import warnings
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import sparse

from glsim.errors import RendererClosedError, SceneError
from glsim.limits import check_gl_target, check_image_size, check_memory, keep
from glsim.scene import quadratic as qd
from glsim.scene.bilinear import bilinear
from glsim.scene.camera import Camera, to_camera
from glsim.effects import (prepare as prepare_effects, shading_terms, spread as spread_rows, through_blur,
                           through_camera_effects)
from glsim.effects import dof, motion, noise as noisemod
from glsim.stages.geometry import MeshGeometry, StepGeometry
from glsim.io.images import quantize as quantize_image, saturated_fraction
from glsim.io.truth import Truth, pixel_positions
from glsim.stages.quadview import fast_local_coords as quadratic_fast_coords
from glsim.stages.view import View, coverage, make_view, warn_unseen
from glsim.backends import make_backend
from glsim.backends.contract import Curved, Request
from glsim.io.fe import specimen_mesh
from glsim.stages.reference import make_reference, require_dots
from glsim.stages import interp, jacobian as jac
from glsim.scene import Render, Scene
from glsim.scene.optional import row_offsets

SEEN_KEPT = 64              # (camera, step) views whose "seen" verdict is kept


@dataclass(frozen=True, eq=False)
class Result:
    """One rendered image: float32 (H, W) grey levels in [0, 1] of full scale (quantised: the
    camera's integers, see :meth:`Renderer.render`)."""
    image: np.ndarray
    camera: Camera
    step: int
    backend: str
    options: Render
    seconds: float
    truth: Truth | None = None
    stages: tuple[str, ...] = ()      # the pipeline stages / GL passes that ran
    specimen: Callable[[], np.ndarray] | None = field(default=None, repr=False)  # makes ``coverage`` when first asked
    jacobian: object | None = None    # render(jacobian=True): scipy.sparse CSR, pixels × 3·nodes (docs/jacobian.md)
    rig_jacobian: object | None = None   # render(rig=True): CSR, pixels × 23 camera parameters (jacobian.RIG_COLUMNS)

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
        return saturated_fraction(self.image, self.coverage, self.camera.bit_depth)


class _Submitted(NamedTuple):
    """A request handed to the backend (its token), with what finishing its Result needs (a
    tuple: made per image, in fewer steps than a frozen dataclass)."""
    token: object
    camera: Camera
    step: int
    options: Render
    truth: bool
    quantize: bool
    step_geo: StepGeometry   # the step's deformed nodes and their box
    curved: bool
    seconds: float      # host time of the submit


class Renderer:
    """Renders one scene with one backend; holds the mesh, reference and backend resources."""

    def __init__(self, scene: Scene, backend: str | None = None, ctx=None, mesh=None, reference=None):
        """``mesh`` / ``reference`` replace the scene's specimen mesh and reference image
        (e.g. a calibration target made in code); ``ctx`` shares a GL context."""
        self.scene = scene
        self.mesh = mesh if mesh is not None else specimen_mesh(scene)
        self._pieces = None
        self.reference = reference if reference is not None else make_reference(scene, self.drawn_mesh)
        self.backend_name = backend or scene.render.backend
        self.backend = make_backend(self.backend_name, self.reference, ctx)
        self._geometry: MeshGeometry | None = None
        self._closed = False
        self._seen: dict[tuple, bool] = {}    # (camera, step) → whether it sees the specimen (_specimen)
        self._jobs: dict[tuple, tuple] = {}   # (camera, truth, options) → (scene, Render, Camera, index) (_job_setup)
        self._ref_coeffs: dict[str, np.ndarray] = {}   # float64 interpolant coefficients (the Jacobian's gradient)
        if limit := self.backend.capabilities.max_size:   # the reference image is one texture
            H, W = self.reference.image.shape
            check_image_size("speckle", W, H, "the reference image", "give a smaller image, or a smaller "
                             "speckle.oversample", limit)

    def check_size(self, camera: int | str, truth: bool = False, opts: Render | None = None) -> None:
        """SceneError if rendering ``camera`` with ``opts`` (default: the scene's [render]) needs a device
        target over the backend's limit (``capabilities.max_size``) or more memory than this process may use (:mod:`glsim.limits`)."""
        cam = self.scene.camera(camera)
        spp = (opts or self.scene.render).samples_per_pixel
        if limit := self.backend.capabilities.max_size:
            check_gl_target("render.samples_per_pixel", cam.size, spp, limit)
        check_memory(f"cameras[{self.scene.cameras.index(cam)}].size", cam.size, spp, truth)

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._closed = True
        self.backend.close()

    def _require_open(self) -> None:
        """Refuse to render once closed: the GL backend's objects are released (moderngl would
        fail deep inside with an unrelated AttributeError) and the CPU's would go on regardless."""
        if self._closed:
            raise RendererClosedError("this renderer is closed (its `with` block ended or close() was called) "
                                      "— render inside the `with` block, or make a new Renderer")

    @property
    def pieces(self) -> qd.Pieces | None:
        """For a quadratic mesh, its linear pieces (what the fast mode draws); None otherwise."""
        if self.mesh.is_quadratic:
            n = self.scene.render.pieces
            if self._pieces is None:
                self._pieces = qd.linearize(self.mesh, n)
            elif self._pieces.n != n:   # (a scene swapped in with other pieces: its caches would not fit)
                raise SceneError("render.pieces", f"{n} differs from the {self._pieces.n} this renderer cut its "
                                 "quadratic mesh into", "make a Renderer for the scene with the other pieces")
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

    def render(self, camera: int | str = 0, step: int = 0, truth: bool = False, quantize: bool = False,
               jacobian: bool = False, rig: bool = False, **options) -> Result:
        """Render one image. ``options`` override the scene's [render] table (mode, …).
        ``quantize``: the image as the camera writes it (:func:`glsim.io.images.quantize` at its
        bit depth: uint8, or uint16 for 10–16 bits), quantised on the GPU where it can be exactly
        (GL with float64), else in numpy — the same bits either way.

        Both backends take the same request (glsim.backends.contract): the view as a
        :class:`ViewSpec` (the camera's transform; the mesh and the step's nodes are shared),
        the effects, and for a quadratic mesh in exact and q4 its curved patches.
        ``jacobian``: also ``Result.jacobian``, the noise-free image's derivative with respect to
        the nodal displacements (:mod:`glsim.stages.jacobian`; refused by name where it cannot be made);
        ``rig``: that and ``Result.rig_jacobian``, with respect to the camera's pose and intrinsics."""
        self._require_open()
        jacobian = jacobian or rig
        if self.scene.exposure is not None:   # motion over the exposure, a rolling shutter
            return self._moving(camera, step, truth, quantize, jacobian, rig, options)
        if not jacobian:
            return self._finish(self._submit(camera, step, truth, quantize, options))
        opts = self._options(options)
        jac.check_request(self.scene, opts, self.reference.dots)
        # the image's own pixel-centre raster is the samples' at 1 spp (not fast's of a quadratic
        # mesh: a Truth is of the patches, the Jacobian of the pieces it draws)
        own = opts.supersampling == 1 and not (opts.mode == "fast" and self.mesh.is_quadratic)
        res = self._finish(self._submit(camera, step, truth or own, quantize, options,
                                        polish=truth or opts.mode != "fast"))   # (fast's Jacobian: elements only)
        raster = {"element": res.truth.element.ravel(), "xi": res.truth.xi.ravel(), "eta": res.truth.eta.ravel()} \
            if own else None
        J, J_rig = self._jacobian(res.camera, step, opts, raster, rig)
        return dataclasses.replace(res, truth=res.truth if truth else None,
                                   **self._through_camera_effects(res.camera, J, J_rig,
                                                                  gain_term=self._gain_term(res.camera, step, opts, rig)))

    def _gain_term(self, cam: Camera, step: int, opts: Render, rig: bool, tl=None, taus=(0.0,), rows=None):
        """The rig Jacobian's share of the vignetting gain's own change with the intrinsics and
        distortion: diag(the image before vignetting) · ∂gain/∂params (W·H × 23, CSR), or None;
        over an exposure (``tl``) the image is its sub-frames' (at ``taus``) mean; ``rows``: a
        rolling shutter's (row, time offset) pairs, each row's image its own sub-frames' (one-row
        cameras)."""
        if not rig or self.scene.vignetting is None:
            return None
        from glsim.effects.vignetting import flat_field_rig_jacobian

        parts = [(cam, 0.0)] if rows is None else [(motion.row_band(cam, row)[0], t) for row, t in rows]
        before = np.concatenate([sum(self._image_before(c, step, opts, tl, t + tau, blur=True).ravel() for tau in taus)
                                 for c, t in parts]) / len(taus)
        return sparse.csr_matrix(before.reshape(-1, 1) * flat_field_rig_jacobian(cam, self.scene.vignetting))

    def _through_camera_effects(self, cam: Camera, J, J_rig, stages=None, gain_term=None) -> dict:
        """``jacobian`` and ``rig_jacobian`` of ``cam``'s image from the raster's: through the
        camera effects that act on the image linearly (:func:`glsim.effects.through_camera_effects`;
        ``stages``: only those; ``gain_term``: the rig Jacobian's vignetting-gain share)."""
        index = self._camera_index(cam)
        return {"jacobian": through_camera_effects(J, self.scene, cam, index, stages),
                "rig_jacobian": None if J_rig is None else through_camera_effects(J_rig, self.scene, cam, index, stages,
                                                                                  gain_term)}

    def _moving(self, camera, step: int, truth: bool, quantize: bool, jacobian: bool, rig: bool,
                options: dict) -> Result:
        """:meth:`render` with ``[exposure]`` (:mod:`glsim.effects.motion`): per row of a rolling
        shutter (else once) the mean of the sub-frames, then fixed-pattern and temporal noise;
        ``jacobian``: the mean of the sub-frames' Jacobians, each chained through its state's
        derivative with respect to the step's nodes (:meth:`glsim.effects.motion.Timeline.derivative`)."""
        t0, scene, mesh = time.perf_counter(), self.scene, self.drawn_mesh
        opts = self._options(options)
        if jacobian:
            jac.check_request(scene, opts, self.reference.dots)
        self.check_size(camera, truth, opts)
        cam, ex = scene.camera(camera), scene.exposure
        rows, tl, taus = self.exposure_schedule(cam, step)
        rolling = rows[0][0] is not None
        one = opts.supersampling == 1   # (a sub-frame's own raster is its samples')
        images, truths, jacobians = [], [], []
        for row, t in rows:
            frames = [self._frame(cam, step, t + tau, tl, opts, (truth and tau == 0) or (jacobian and one), row)
                      for tau in taus]
            images.append(sum(out.image.astype(np.float64) for out, _ in frames) / len(taus))
            if jacobian:
                Js, rigs = zip(*(self._sub_jacobian(cam, step, opts, out.samples if one else None, rig, tl, t + tau, row)
                                 for (out, _), tau in zip(frames, taus)))
                jacobians.append((sum(Js) / len(taus), sum(rigs) / len(taus) if rig else None))
            if truth:
                out = next((out for (out, _), tau in zip(frames, taus) if tau == 0), None) or \
                    self._frame(cam, step, t, tl, opts, True, row)[0]
                curved = self.mesh.is_quadratic and opts.mode != "fast"
                raster = out.samples if curved or not self.mesh.is_quadratic else self._fast_to_patches(out.samples)
                tr = self._truth(out.image.shape[::-1], tl.at(t, self.mesh.deformed), raster)
                truths.append(self._motion_range(tr, cam, tl, t, ex.time))
        (out, fx), image = frames[-1], np.concatenate(images).astype(np.float32)
        stages = tuple(out.stages)
        if fx.fixed_pattern:   # as the backends do, on the whole image
            image = noisemod.fixed_pattern(image, fx.sensor.prnu, fx.sensor.dsnu, fx.bit_depth,
                                           fx.fpn_seed).astype(np.float32)
            stages += ("fixed_pattern",)
        if fx.noise is not None:
            image = noisemod.add_noise(image, fx.noise, fx.bit_depth, fx.noise_seed, fx.variance)
            stages += ("noise",)
        specimen = self._specimen(cam, tl.at(0.0, mesh.deformed), mesh.quads)   # (warns if unseen at mid-frame)
        if rolling:   # each row's own state
            specimen = lambda: np.concatenate([coverage(motion.row_band(cam, row)[0], tl.at(t, mesh.deformed),  # noqa: E731
                                                        mesh.quads) for row, t in rows])
        derivatives = {}
        if jacobian:
            J = sparse.csr_matrix(sparse.vstack([j for j, _ in jacobians]))
            J_rig = sparse.csr_matrix(sparse.vstack([r for _, r in jacobians])) if rig else None
            gain_term = None if rolling and self._banded else \
                self._gain_term(cam, step, opts, rig, tl, taus, rows if rolling else None)   # (banded: per band)
            derivatives = self._through_camera_effects(cam, J, J_rig, ("prnu",) if rolling and self._banded else None,
                                                       gain_term)
        return Result(image=quantize_image(image, cam.bit_depth) if quantize else image, camera=cam, step=step,
                      backend=self.backend_name, options=opts, seconds=time.perf_counter() - t0,
                      truth=self._stack(truths) if truth else None, stages=stages, specimen=specimen, **derivatives)

    def exposure_schedule(self, camera: int | str | Camera, step: int):
        """The sub-frames that make ``camera``'s image at ``step`` under the scene's [exposure]
        (:mod:`glsim.effects.motion`): the rows of a rolling shutter, each with its exposure
        centre (s from the step's time; [(None, 0.0)]: the whole frame at once), the step's
        :class:`~glsim.effects.motion.Timeline` and the midpoint rule's offsets τ_i (s); each
        row's image is the mean of its renders at centre + τ_i (:meth:`sub_frames`)."""
        cam = camera if isinstance(camera, Camera) else self.scene.camera(camera)
        ex, sensor = self.scene.exposure, self.scene.sensor
        if ex is None:
            raise SceneError("exposure", "the scene has no [exposure] table, so each image is one render",
                             "add [exposure] (time, samples, velocity …) to average sub-frames")
        line = sensor.line_time if sensor is not None else 0.0
        rows = list(enumerate(row_offsets(cam.height, line))) if line > 0 else [(None, 0.0)]
        return rows, motion.timeline(ex, self.mesh, step), motion.sample_offsets(ex.time, ex.samples)

    def sub_frames(self, camera: int | str, step: int, truth: bool = False, **options):
        """The renders :meth:`render` averages for ``camera``'s image at ``step`` under the
        scene's [exposure], in :meth:`exposure_schedule`'s order (rows, then τ_i): (row or None,
        τ s from the step's time, the state's nodes (world mm, of the mesh drawn), the Raster —
        the row's, cut from its band — without noise; ``truth``: with its samples)."""
        self._require_open()
        cam, opts = self.scene.camera(camera), self._options(options)
        rows, tl, taus = self.exposure_schedule(cam, step)
        for row, t in rows:
            for tau in taus:
                yield row, t + tau, tl.at(t + tau, self.drawn_mesh.deformed), \
                    self._frame(cam, step, t + tau, tl, opts, truth, row)[0]

    def _camera_index(self, cam: Camera) -> int:
        """``cam``'s index in the scene (a band camera's or a sample camera's: its camera's, by name)."""
        return self.scene.cameras.index(self.scene.camera(cam.name))

    @property
    def _banded(self) -> bool:
        """Whether a rolling shutter's rows are rendered as bands (:meth:`_frame`): the depth of
        field or the PSF move light between rows."""
        return self.scene.optics is not None or self.scene.psf is not None

    def _row_band(self, cam: Camera, step: int, state, nodes: np.ndarray, row: int):
        """A rolling shutter's ``row`` as the band of rows whose light the depth of field and the
        PSF move into it at this state's depths (:func:`glsim.effects.spread`): the band's camera,
        the row's index in it, and the corner depths (mm; empty without [optics])."""
        view = self.geometry.view(cam, step, state, nodes)
        depths = view.corner_depths() if self.scene.optics is not None else np.empty(0)
        return (*motion.row_band(cam, row, spread_rows(self.scene, depths)), depths)

    def _sub_jacobian(self, cam: Camera, step: int, opts: Render, raster: dict | None, rig: bool,
                      tl: "motion.Timeline", tau: float, row: int | None):
        """One sub-frame's (J, J_rig) in :meth:`_moving`: of ``cam``, or of a rolling shutter's
        ``row`` — the row's one-row camera with its own ``raster``, or, where the rows are
        banded, the band's Jacobian (its raster rendered), through its depth of field, vignetting
        and PSF as the band is rendered, cut to the row."""
        if row is None or not self._banded:
            return self._jacobian(cam if row is None else motion.row_band(cam, row)[0], step, opts, raster, rig, tl, tau)
        band, at, _ = self._row_band(cam, step, None if tau == 0 else float(tau), tl.at(tau, self.drawn_mesh.deformed),
                                     row)
        J, J_rig = self._jacobian(band, step, opts, None, rig, tl, tau)
        index = self._camera_index(cam)
        rows = slice(at * cam.width, (at + 1) * cam.width)
        stages = ("vignetting", "psf")
        return (through_camera_effects(J, self.scene, band, index, stages)[rows],
                None if J_rig is None else through_camera_effects(J_rig, self.scene, band, index, stages,
                                                                  self._gain_term(band, step, opts, rig, tl, (tau,)))[rows])

    def _frame(self, cam: Camera, step: int, tau: float, tl: "motion.Timeline", opts: Render, truth: bool,
               row: int | None = None):
        """One sub-frame of :meth:`_moving`: the state τ s from ``step``'s time, rendered without
        temporal and fixed-pattern noise; (Raster, the Effects). ``row``: only that row of
        ``cam`` (a rolling shutter's), rendered as the band of rows whose light the depth of
        field and the PSF move into it (:func:`glsim.effects.spread`) and cut to it."""
        mesh, state = self.drawn_mesh, None if tau == 0 else float(tau)
        nodes = tl.at(tau, mesh.deformed)
        curved = self._curved(opts, step, tl, tau)
        index = self._camera_index(cam)
        if row is None:
            view = self.geometry.view(cam, step, state, nodes)
            depths = view.corner_depths() if self.scene.optics is not None else np.empty(0)
        else:
            cam, at, depths = self._row_band(cam, step, state, nodes, row)
            view = self.geometry.view(cam, step, state, nodes)
        fx = prepare_effects(self.scene, nodes, mesh.quads, cam, index, step, depths,
                             normals=not self.backend.capabilities.device_geometry)
        out = self.backend.render(Request(view, opts, truth, dataclasses.replace(fx, noise=None, sensor=None), curved))
        return (out if row is None else motion.band_row(out, at, cam.width)), fx

    def _jacobian(self, cam: Camera, step: int, opts: Render, raster: dict | None, rig: bool,
                  tl: "motion.Timeline | None" = None, tau: float = 0.0):
        """The image Jacobian (glsim.stages.jacobian.image_jacobian) from the backend's float64
        raster of every sample: for s > 1 rendered as the pixels of the finer sample camera
        (its warnings were the image's). ``tl``: of the state τ s from the step's time
        (:meth:`_moving`'s sub-frame), chained to the step's own displacements by the state's
        derivative (:meth:`glsim.effects.motion.Timeline.derivative`)."""
        s, mesh = opts.supersampling, self.mesh
        state = None if tl is None or tau == 0 else float(tau)
        deformed = mesh.deformed(step) if tl is None else tl.at(tau, mesh.deformed)
        drawn = self.drawn_mesh.deformed(step) if tl is None else tl.at(tau, self.drawn_mesh.deformed)
        aperture = math.sqrt(self.scene.sensor.fill_factor) if self.scene.sensor is not None else 1.0
        if raster is None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                drawn_state = None if tl is None else drawn   # (the step's own view when not moving)
                one = dataclasses.replace(opts, samples_per_pixel=1)
                curved = self._curved(opts, step, tl, tau)
                polish = opts.mode != "fast"   # (fast's Jacobian uses the raster's elements only)
                if aperture == 1.0:
                    view = self.geometry.view(jac.sample_camera(cam, s), step, state, drawn_state)
                    raster = self.backend.render(Request(view, one, True, curved=curved, polish=polish)).samples
                else:   # each sample offset as a camera shifted by it: (H, s, W, s) → the sample camera's order
                    parts = [[self.backend.render(Request(self.geometry.view(shifted, step, state, drawn_state), one, True,
                                                          curved=curved, polish=polish)).samples for shifted in row]
                             for row in jac.shifted_cameras(cam, s, aperture)]
                    W, H = cam.size
                    raster = {k: np.stack([np.stack([p[k].reshape(H, W) for p in row], -1) for row in parts], 1)
                              .reshape(-1) for k in ("element", "xi", "eta")}
        value, gradient = self._reference_functions(opts.interpolation)
        pieces = opts.mode == "fast" and mesh.is_quadratic   # fast draws the pieces: their nodes, then chained
        of = self.drawn_mesh if pieces else mesh             # the mesh differentiated
        shading = None
        if self.scene.lighting is not None:   # the drawn mesh's normals (a quadratic mesh's pieces')
            shading = shading_terms(self.scene, drawn, self.drawn_mesh.quads, cam, value, None if pieces else self.pieces)
        J, J_rig, depth = jac.image_jacobian(
            cam, self.reference.camera, jac.MeshState(of.nodes, drawn if pieces else deformed, of.quads, of.patches),
            raster, gradient, jac.JacobianOptions(opts.mode, s, aperture, rig, self.scene.optics is not None), shading)
        if pieces:   # the pieces' nodes as weights of the mesh's (PiecesMesh.grid_matrix)
            G = sparse.kron(self.drawn_mesh.grid_matrix(), sparse.identity(3), format="csr")
            J = J @ G
            depth = None if depth is None else (depth[0], depth[1] @ G, depth[2])
        if depth is not None:   # through the depth of field's blur, of this state's unblurred image
            z, J_z, J_z_rig = depth
            W, H = cam.size
            n = J.shape[1]
            out = through_blur(J if J_rig is None else sparse.hstack([J, J_rig], format="csr"),
                               J_z if J_rig is None else sparse.hstack([J_z, J_z_rig], format="csr"),
                               self._image_before(cam, step, opts, tl, tau, blur=False), dof.pixel_depth(z, H, W, s),
                               self.scene.optics)
            J, J_rig = (out, None) if J_rig is None else (out[:, :n], out[:, n:])
        if tl is not None:   # ∂g/∂u_k = ∂g/∂X(τ) · ∂X(τ)/∂X_k, per node
            J = J @ sparse.kron(sparse.identity(mesh.n_nodes), tl.derivative(tau), format="csr")
        return J, J_rig

    def _reference_functions(self, method: str):
        """The reference grey's value and gradient (grey per px) at reference points uv (n, 2), in
        float64: the interpolant of ``method`` (its coefficients made once), or the procedural
        speckle's exact dots (glsim.scene.speckle.evaluate, gradient)."""
        if method == "procedural":
            from glsim.scene import speckle

            dots = require_dots(self.reference.dots)
            grid = speckle.dot_grid(dots)
            return (lambda uv: speckle.evaluate(dots, uv, grid)), (lambda uv: speckle.gradient(dots, uv, grid))
        if method not in self._ref_coeffs:
            self._ref_coeffs[method] = interp.prepare(self.reference.image, method, np.float64)
        coeffs = self._ref_coeffs[method]
        return (lambda uv: interp.sample(coeffs, uv, method)), (lambda uv: interp.gradient(coeffs, uv, method))

    def _image_before(self, cam: Camera, step: int, opts: Render, tl, tau: float, blur: bool) -> np.ndarray:
        """``cam``'s image (H, W) float64 at ``step`` (or the state τ s from it on ``tl``) before
        the camera effects and noise: lit, supersampled, and with its depth of field if ``blur``."""
        state = None if tl is None or tau == 0 else float(tau)
        nodes = self.drawn_mesh.deformed(step) if tl is None else tl.at(tau, self.drawn_mesh.deformed)
        view = self.geometry.view(cam, step, state, None if tl is None else nodes)
        index = self._camera_index(cam)
        fx = prepare_effects(self.scene, nodes, self.drawn_mesh.quads, cam, index, step, view.corner_depths(),
                             normals=not self.backend.capabilities.device_geometry)
        fx = dataclasses.replace(fx, noise=None, sensor=None, vignette=None, psf=None,
                                 **({} if blur else {"optics": None, "sigma_max": 0.0}))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out = self.backend.render(Request(view, opts, False, fx, self._curved(opts, step, tl, tau)))
        return out.image.astype(np.float64)

    def render_many(self, jobs: Iterable, depth: int = 2) -> Iterator[Result]:
        """The Results of ``jobs`` in order, pipelined: request k + depth − 1 is submitted before
        request k is collected, so the GL backend's passes for the next image run while this
        one's read-back is mapped and finished on the host (the oracle renders one at a time).
        A job is a mapping of :meth:`render`'s arguments (``camera``, ``step``, ``truth``,
        ``quantize``, render options) or a ``(camera, step)`` pair. The same images and truth,
        bit for bit, as :meth:`render`. ``Result.seconds``: the host time of the job's submit and
        collect (a collect waits for the GPU if it has not finished)."""
        self._require_open()
        if depth < 1:
            raise SceneError("depth", f"{depth!r} is not a positive integer", "give 1 (no overlap) or more")
        pending: collections.deque = collections.deque()
        try:
            for job in jobs:
                self._require_open()   # (closed between two of its Results)
                args = dict(job) if isinstance(job, Mapping) else dict(zip(("camera", "step"), job))
                if self.scene.exposure is not None or args.get("jacobian") or args.get("rig"):
                    while pending:   # (in order) then several renders per image (glsim.effects.motion), or a
                        yield self._finish(pending.popleft())    # Jacobian from a second raster
                    yield self.render(**args)
                    continue
                pending.append(self._submit(args.pop("camera", 0), args.pop("step", 0), args.pop("truth", False),
                                            args.pop("quantize", False), args))
                if len(pending) >= depth:
                    yield self._finish(pending.popleft())
            while pending:
                yield self._finish(pending.popleft())
        finally:   # stopped early: what was submitted is collected (its buffers go back), unseen
            while pending and not self._closed:
                self.backend.collect(pending.popleft().token)

    def _job_setup(self, camera, truth: bool, options: dict) -> tuple[Render, Camera, int]:
        """A job's render options, camera and the camera's index in the scene, its size checked
        (:meth:`check_size`); kept per scene, camera, truth and options, so a stream of like
        jobs checks each once."""
        try:
            key = (camera, truth, tuple(sorted(options.items())))
            hash(key)
        except TypeError:   # (an unhashable option value: the scene's own check rejects it)
            key = None
        hit = self._jobs.get(key) if key is not None else None
        if hit is not None and hit[0] is self.scene:
            return hit[1:]
        opts = self._options(options)
        self.check_size(camera, truth, opts)
        cam = self.scene.camera(camera)
        index = self.scene.cameras.index(cam)
        if key is not None:
            keep(self._jobs, key, (self.scene, opts, cam, index), SEEN_KEPT)
        return opts, cam, index

    def _curved(self, opts: Render, step: int, tl: "motion.Timeline | None" = None, tau: float = 0.0) -> Curved | None:
        """A quadratic mesh's curved patches as modes exact and q4 map on them (None otherwise)
        at ``step``, or at its state τ s on (``tl``: :meth:`_moving`'s sub-frames), keyed as
        :meth:`glsim.stages.geometry.MeshGeometry.step` keys it."""
        if not self.mesh.is_quadratic or opts.mode == "fast":
            return None
        if tl is None or tau == 0:
            return Curved(self.mesh, self.pieces, step)
        return Curved(self.mesh, self.pieces, (step, float(tau)), tl.at(tau, self.mesh.deformed))

    def _options(self, options: dict) -> Render:
        """The scene's [render] table with ``options`` (a render call's) applied; ``pieces`` is
        the renderer's (its quadratic mesh is cut once), not changed per call."""
        if not options:
            return self.scene.render
        opts = self.scene.replace(render=options).render
        if opts.pieces != self.scene.render.pieces:
            raise SceneError("render.pieces", f"{opts.pieces} differs from the renderer's {self.scene.render.pieces}: "
                             "a renderer cuts its quadratic mesh once", "give pieces in the scene's [render] table "
                             "(a Renderer of scene.replace(render={'pieces': n}))")
        return opts

    def _submit(self, camera, step: int, truth: bool, quantize: bool, options: dict, polish: bool = True) -> "_Submitted":
        t0 = time.perf_counter()
        opts, cam, index = self._job_setup(camera, truth, options)
        view = self.geometry.view(cam, step)
        deformed = view.step_geo.deformed
        depths = view.corner_depths() if self.scene.optics is not None else np.empty(0)
        fx = prepare_effects(self.scene, deformed, self.drawn_mesh.quads, cam, index, step,
                             depths, normals=not self.backend.capabilities.device_geometry)
        curved = self._curved(opts, step)
        token = self.backend.submit(Request(view, opts, truth, fx, curved, cam.bit_depth if quantize else None, polish))
        return _Submitted(token, cam, step, opts, truth, quantize, view.step_geo, curved is not None,
                          time.perf_counter() - t0)

    def _finish(self, job: "_Submitted") -> Result:
        t0 = time.perf_counter()
        cam, step, out = job.camera, job.step, self.backend.collect(job.token)
        image = quantize_image(out.image, cam.bit_depth) if job.quantize and out.image.dtype.kind == "f" else out.image
        seconds = job.seconds + time.perf_counter() - t0
        tr = None
        if job.truth and self.mesh.is_quadratic:   # the raster of the patches (fast: of the pieces, mapped here)
            tr = self._truth(cam.size, self.mesh.deformed(step),
                             out.samples if job.curved else self._fast_to_patches(out.samples))
        elif job.truth:
            tr = self._truth(cam.size, job.step_geo.deformed, out.samples)
        return Result(image=image, camera=cam, step=step, backend=self.backend_name,
                      options=job.options, seconds=seconds, truth=tr, stages=out.stages,
                      specimen=self._specimen(cam, job.step_geo.deformed, self.drawn_mesh.quads, step,
                                              job.step_geo.box))

    def _specimen(self, cam: Camera, deformed: np.ndarray, quads: np.ndarray, step=None,
                  box=None) -> Callable[[], np.ndarray]:
        """Warns when ``cam`` sees none of the specimen (RenderWarning, saying why); returns what
        makes its pixel mask on demand. ``step``: a view of this camera object found seen at
        that step is not looked at again (an unseen one warns each time); ``box``: the nodes'
        extent, if known."""
        key = (cam, step)
        if step is None or not self._seen.get(key, False):
            seen = warn_unseen(cam, deformed, quads, stacklevel=6, box=box)
            if step is not None:
                keep(self._seen, key, seen, SEEN_KEPT)
        return lambda: coverage(cam, deformed, quads)

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

    def _stack(self, rows: list[Truth]) -> Truth:
        """A rolling shutter's rows' truths as one (:func:`glsim.effects.motion.stack`; the
        library's compact renderer stacks its own)."""
        return motion.stack(rows)

    def _motion_range(self, tr: Truth, cam: Camera, tl: "motion.Timeline", tau: float, duration: float) -> Truth:
        """``tr`` (rendered at τ s) with where its material points are at the exposure's start
        and end (:func:`glsim.effects.motion.motion_range`)."""
        return motion.motion_range(tr, self.mesh, cam, tl, tau, duration, self._positions)

    def _positions(self, nodes: np.ndarray, elements: np.ndarray, xi, eta) -> np.ndarray:
        """Points (…, 3) mm at (ξ, η) of the FE mesh's ``elements`` with node positions ``nodes``:
        by the patches' own shape functions for quadratic elements, else bilinear."""
        if self.mesh.is_quadratic:
            return qd.evaluate(qd.patch_points(self.mesh.patches[elements], nodes), xi, eta)
        return bilinear(nodes[self.mesh.quads[elements]], xi, eta)

    def _truth(self, size, deformed: np.ndarray, raster: dict) -> Truth:
        """Truth maps from a raster of the FE mesh's elements (element, ξ, η, ref_uv; a quadratic
        mesh's patches) over ``size`` (W, H) px, its nodes at ``deformed``."""
        W, H = size
        elem = raster["element"].reshape(H, W)
        mask = elem >= 0
        xi = np.where(mask, raster["xi"].reshape(H, W), np.nan)
        eta = np.where(mask, raster["eta"].reshape(H, W), np.nan)
        ref = np.where(mask[..., None], raster["ref_uv"].reshape(H, W, 2), np.nan)
        cam1, nodes, evaluate = self.scene.cameras[0], self.mesh.nodes, self._positions
        e, x, y = elem[mask], xi[mask], eta[mask]
        return Truth(mask=mask, element=elem, xi=xi, eta=eta, ref_uv=ref,
                     positions=pixel_positions(mask, lambda: (to_camera(evaluate(nodes, e, x, y), cam1),
                                                              to_camera(evaluate(deformed, e, x, y), cam1))))


def render(scene: Scene, camera: int | str = 0, step: int = 0, backend: str | None = None,
           truth: bool = False, **options) -> Result:
    """Render one image of ``scene`` (convenience wrapper around :class:`Renderer`)."""
    with Renderer(scene, backend) as r:
        return r.render(camera, step, truth, **options)
