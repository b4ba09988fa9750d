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

What one Result is made of beyond a single render is composed in :mod:`glsim.compose`: the
truth (a :class:`~glsim.compose.truth.TruthAssembler` given to the Renderer), the Jacobian chain
(:mod:`glsim.compose.chain`) and an exposure's sub-frames and rolling-shutter rows
(:mod:`glsim.compose.exposure`).
"""
from __future__ import annotations

import collections
import dataclasses
import functools
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from glsim.backends import make_backend
from glsim.backends.contract import Request
from glsim.compose import chain, exposure
from glsim.compose.drawing import Drawing, curved_patches
from glsim.compose.truth import PixelMaps, TruthAssembler, element_raster
from glsim.effects import dof
from glsim.effects import prepare as prepare_effects
from glsim.errors import RendererClosedError, SceneError
from glsim.io.fe import specimen_mesh
from glsim.io.images import quantize as quantize_image, saturated_fraction
from glsim.io.truth import Truth
from glsim.limits import check_gl_target, check_image_size, check_memory, keep
from glsim.scene import Render, Scene
from glsim.scene import quadratic as qd
from glsim.scene.camera import Camera, to_camera
from glsim.imaging import jacobian as jac
from glsim.imaging.geometry import MeshGeometry, StepGeometry
from glsim.imaging.reference import make_reference
from glsim.imaging.view import View, coverage, make_view, warn_unseen

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
        """(H, W) bool: the specimen's pixels (:func:`glsim.imaging.view.coverage`), made on first
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
    """A request handed to the backend (its token), with what finishing its Result needs."""
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

    def __init__(self, scene: Scene, backend: str | None = None, ctx=None, mesh=None, reference=None,
                 truth_assembler: TruthAssembler | None = None):
        """``mesh`` / ``reference`` replace the scene's specimen mesh and reference image
        (e.g. a calibration target made in code); ``ctx`` shares a GL context;
        ``truth_assembler`` makes each render's truth from its raster (default: the per-pixel
        maps, :class:`glsim.compose.truth.PixelMaps`)."""
        self.scene = scene
        self.truth_assembler = truth_assembler if truth_assembler is not None else PixelMaps()
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

    def load_displacements(self, scene: Scene, mesh) -> None:
        """Render ``scene`` with ``mesh`` from now on, where only the load steps' displacements differ
        from this renderer's: the same undeformed nodes and elements (so the same reference image,
        which the caller's scene must also share: speckle, camera 0, backend). The reference image
        and the backend's programs are kept, what was cached of the old displacements is dropped
        (the mesh geometry, the views seen, per-job set-up). Training sets render many random
        fields under one speckle pattern this way: 37 ms a 256² sample on llvmpipe against 54 ms
        for a new Renderer (the reference texture prefiltered and uploaded again)."""
        self._require_open()
        same = (mesh.nodes.shape == self.mesh.nodes.shape and np.array_equal(mesh.nodes, self.mesh.nodes)
                and np.array_equal(mesh.quads, self.mesh.quads) and not mesh.is_quadratic
                and not self.mesh.is_quadratic)
        if not same:
            raise ValueError("load_displacements: the new mesh's undeformed nodes or elements differ (or it is "
                             "quadratic) — make a new Renderer")
        self.scene, self.mesh = scene, mesh
        self._geometry = None
        self._seen.clear()
        self._jobs.clear()

    def check_size(self, camera: int | str, truth: bool = False, opts: Render | None = None) -> None:
        """SceneError if rendering ``camera`` with ``opts`` (default: the scene's [render]) needs a device
        target over the backend's limit (``capabilities.max_size``) or more memory than this process may
        use (:mod:`glsim.limits`)."""
        cam = self.scene.camera(camera)
        spp = (opts or self.scene.render).samples_per_pixel
        if limit := self.backend.capabilities.max_size:
            check_gl_target("render.samples_per_pixel", cam.size, spp, limit)
        check_memory(f"cameras[{self.scene.cameras.index(cam)}].size", cam.size, spp, truth)
        if self.scene.optics is not None:   # before anything is written: the undeformed specimen's depths
            dof.check_depths(to_camera(self.mesh.nodes, cam)[:, 2], self.scene.optics,
                             f"camera {cam.name}: the specimen")

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
        the nodal displacements (:mod:`glsim.imaging.jacobian`; refused by name where it cannot be made);
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
        return dataclasses.replace(res, truth=res.truth if truth else None,
                                   **chain.jacobians(self._drawing(), res.camera, step, opts, raster, rig))

    def _drawing(self) -> Drawing:
        """What the compositions of :mod:`glsim.compose` need of this renderer, for its current scene."""
        return Drawing(self.scene, self.mesh, self.pieces, self.reference, self.backend, self.geometry,
                       self._ref_coeffs)

    def _moving(self, camera, step: int, truth: bool, quantize: bool, jacobian: bool, rig: bool,
                options: dict) -> Result:
        """:meth:`render` with ``[exposure]``: :func:`glsim.compose.exposure.expose`."""
        t0 = time.perf_counter()
        opts = self._options(options)
        if jacobian:
            jac.check_request(self.scene, opts, self.reference.dots)
        self.check_size(camera, truth, opts)
        cam = self.scene.camera(camera)
        out = exposure.expose(self._drawing(), cam, step, opts, truth, jacobian, rig, self.truth_assembler)
        mesh = self.drawn_mesh
        specimen = self._specimen(cam, mesh.deformed(step), mesh.quads)   # (warns if unseen at mid-frame)
        return Result(image=quantize_image(out.image, cam.bit_depth) if quantize else out.image, camera=cam, step=step,
                      backend=self.backend_name, options=opts, seconds=time.perf_counter() - t0, truth=out.truth,
                      stages=out.stages, specimen=out.specimen or specimen, jacobian=out.jacobian,
                      rig_jacobian=out.rig_jacobian)

    def exposure_schedule(self, camera: int | str | Camera, step: int):
        """The sub-frames that make ``camera``'s image at ``step`` under the scene's [exposure]:
        (rows, the step's Timeline, the offsets τ_i), :func:`glsim.compose.exposure.schedule`."""
        cam = camera if isinstance(camera, Camera) else self.scene.camera(camera)
        return exposure.schedule(self.scene, self.mesh, cam, step)

    def sub_frames(self, camera: int | str, step: int, truth: bool = False, **options):
        """The renders :meth:`render` averages for ``camera``'s image at ``step`` under the
        scene's [exposure], in :meth:`exposure_schedule`'s order (rows, then τ_i): (row or None,
        τ s from the step's time, the state's nodes (world mm, of the mesh drawn), the Raster —
        the row's, cut from its band — without noise; ``truth``: with its samples)."""
        self._require_open()
        cam, opts = self.scene.camera(camera), self._options(options)
        yield from exposure.sub_frames(self._drawing(), cam, step, opts, truth)

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

    def _submit(self, camera, step: int, truth: bool, quantize: bool, options: dict,
                polish: bool = True) -> "_Submitted":
        t0 = time.perf_counter()
        opts, cam, index = self._job_setup(camera, truth, options)
        view = self.geometry.view(cam, step)
        deformed = view.step_geo.deformed
        depths = view.corner_depths() if self.scene.optics is not None else np.empty(0)
        fx = prepare_effects(self.scene, deformed, self.drawn_mesh.quads, cam, index, step,
                             depths, normals=not self.backend.capabilities.device_geometry)
        curved = curved_patches(self.mesh, self.pieces, opts, step)
        token = self.backend.submit(Request(view, opts, truth, fx, curved, cam.bit_depth if quantize else None, polish))
        return _Submitted(token, cam, step, opts, truth, quantize, view.step_geo, curved is not None,
                          time.perf_counter() - t0)

    def _finish(self, job: "_Submitted") -> Result:
        t0 = time.perf_counter()
        cam, step, out = job.camera, job.step, self.backend.collect(job.token)
        image = quantize_image(out.image, cam.bit_depth) if job.quantize and out.image.dtype.kind == "f" else out.image
        seconds = job.seconds + time.perf_counter() - t0
        tr = None
        if job.truth:   # of the FE mesh's elements (a quadratic mesh's patches; fast's pieces mapped to them)
            deformed = self.mesh.deformed(step) if self.mesh.is_quadratic else job.step_geo.deformed
            tr = self.truth_assembler.maps(self.mesh, self.scene.cameras[0], cam.size, deformed,
                                           element_raster(self.mesh, self.pieces, self.reference.camera, out.samples,
                                                          job.curved))
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


def render(scene: Scene, camera: int | str = 0, step: int = 0, backend: str | None = None,
           truth: bool = False, **options) -> Result:
    """Render one image of ``scene`` (convenience wrapper around :class:`Renderer`)."""
    with Renderer(scene, backend) as r:
        return r.render(camera, step, truth, **options)
