"""backend="gl": render a :class:`~glsim.imaging.geometry.ViewSpec` with OpenGL shaders.

A request becomes a plan (:func:`glsim.backends.gl.plan.plan`: the deformation program's
#defines and the ordered passes); :class:`GLBackend` executes the plan's passes in order, each by
its step (:mod:`glsim.backends.gl.deform_steps` for the deformation passes,
:meth:`~glsim.backends.gl.imagepasses.ImagePasses.image_step` for the box filter, blur, camera
effects, noise and quantisation), then queues one read-back of the image (and the truth maps
and the view's problem flags: :mod:`glsim.backends.gl.truth_readback`). Every GL object is owned
by one :class:`~glsim.backends.gl.resources.Resources`; programs by the context's
:class:`~glsim.backends.gl.programs.ProgramCache`. The mesh is uploaded once per renderer and
the deformed nodes once per load step (:mod:`glsim.backends.gl.geometry`).
"""
from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from glsim.backends.contract import Capabilities, Raster, Request
from glsim.backends.gl import deform_steps
from glsim.backends.gl.bindings import sampler
from glsim.backends.gl.context import check_error, create_context, driver_info, software_renderer
from glsim.backends.gl.deform_steps import FrameState
from glsim.backends.gl.dots import bind_dots, dot_buffers
from glsim.backends.gl.geometry import GeometryBuffers
from glsim.backends.gl.imagepasses import ImagePasses, blur_setup
from glsim.backends.gl.plan import environment_stage, pixel_stage, plan
from glsim.backends.gl.programs import ProgramCache
from glsim.backends.gl.rays import ray_map
from glsim.backends.gl.readback import Pending, read_texture
from glsim.backends.gl.resources import Resources
from glsim.backends.gl.truth_readback import queue_raster, queue_report
from glsim.backends.gl.uniforms import Uniforms
from glsim.effects import Effects
from glsim.imaging import interp
from glsim.imaging.geometry import ViewSpec
from glsim.imaging.quadview import patch_data, pieces_to_patches

_REF_UNIT = sampler("u_ref")
_DTYPES = {"f4": np.float32, "u1": np.uint8, "u2": np.uint16}   # moderngl texture dtype → numpy
_NO_EFFECTS = Effects()
# the contract's stage names of the image passes (Raster.stages), by plan step
_STAGE_NAMES = {"vignette": "vignette", "psf": "psf", "fpn": "fixed_pattern", "noise": "noise"}


def pack_pairs(c: np.ndarray) -> np.ndarray:
    """(H, W) → (H, W, 4): texel (i, j) holds c at columns i, i + 1 of rows j and j + 1 (the last
    column and row repeated), so interp.glsl reads four taps per fetch."""
    right = np.concatenate([c[:, 1:], c[:, -1:]], axis=1)
    return np.stack([c, right, np.concatenate([c[1:], c[-1:]]), np.concatenate([right[1:], right[-1:]])], axis=-1)


def _light_uniforms(fx) -> dict:
    """Uniform name → float32 array for shade.glsl (lights padded to MAX_LIGHTS ≥ 1)."""
    L, lit = fx.lights, fx.lighting
    n = max(1, len(L.intensity))

    def pad(a, width):
        out = np.zeros((n, width) if width > 1 else n, np.float32)
        out[:len(a)] = a
        return out

    return {"u_light_pos": pad(L.pos, 3), "u_light_dir": pad(L.dir, 3),
            "u_light_intensity": pad(L.intensity, 1), "u_light_att": pad(L.attenuation, 1),
            "u_light_cos_cutoff": pad(L.cos_cutoff, 1), "u_light_cos_inner": pad(L.cos_inner, 1),
            "u_ambient": np.float32(lit.ambient), "u_kr": np.float32(lit.diffuse),
            "u_ks": np.float32(lit.specular), "u_shininess": np.float32(lit.shininess)}


def view_uniforms(view: ViewSpec, geo, patches) -> Uniforms:
    """The uniforms every deformation program and view.comp read: the camera and reference
    models, the transform of the mesh's local frame to the camera's (``view.rotation``,
    ``view.translation``), the sizes, view.glsl's constants for the mesh
    (:meth:`GeometryBuffers.camera_values`), the view's far plane and the sag (px: a quadratic
    mesh's pieces' chord error at this view, else 0)."""
    cam, ref = view.camera, view.ref_camera
    return Uniforms({**geo.camera_values(cam), "u_rot": view.rotation.ravel(), "u_trans": view.translation,
                     "u_intr": cam.intrinsics, "u_dist": cam.distortion.coeffs,
                     "u_valid_r2": cam.distortion.valid_radius() ** 2,
                     "u_ref_intr": ref.intrinsics, "u_ref_dist": ref.distortion.coeffs,
                     "u_ref_valid_r2": ref.distortion.valid_radius() ** 2, "u_size": cam.size,
                     "u_ref_size": ref.size, "u_far": view.far,
                     "u_extra_sag": patches.extra_sag_px if patches is not None else 0.0})


def stage_names(p, fx) -> tuple[str, ...]:
    """The contract's stages a plan runs (Raster.stages): the deformation pass's, then the
    pixel integration's and each image pass's."""
    names = ["raster", "interpolate"] + (["light"] if fx.lighting is not None else [])
    if p.subsamples:
        names.append("subsamples")
    elif any(x.step == "box" for x in p.passes):
        names.append("downsample")
    for x in p.passes:
        name = x.variant.lower() if x.step == "blur" else _STAGE_NAMES.get(x.step)
        if name is not None and (not names or names[-1] != name or x.step == "blur"):
            names.append(name)
    return tuple(names)


@dataclass(frozen=True)
class Frame:
    """A request submitted to the GPU with its read-backs queued (:meth:`GLBackend.submit`);
    :meth:`GLBackend.collect` fetches them."""
    image: Pending
    raster: Callable[[], dict | None]       # the truth raster, fetched and finished (None: not asked)
    report: Callable[[], None]              # the view's warnings, from its fetched problem flags
    stages: tuple[str, ...]
    curved: object = None                   # the request's Curved (the raster is mapped to its patches)
    camera: object = None
    mode: str = "exact"


class GLBackend(ImagePasses):
    """OpenGL renderer over one EGL context (its own, or a shared one passed in): an executor of
    render plans over one resource owner.

    A request is submitted (every pass of its plan queued in order, every read-back queued into
    a pixel-pack buffer: :mod:`glsim.backends.gl.readback`) and collected (the reads mapped);
    ``render`` does both. Pipelined callers (``Renderer.render_many``) submit the next request
    before collecting one. ``last_passes``: the passes the last submit executed, in order."""
    name = "gl"

    def __init__(self, reference_image: np.ndarray, ctx=None, shader_dirs: tuple = (), dots=None):
        """``dots``: the generator's speckle, for ``interpolation = "procedural"``;
        ``shader_dirs`` are searched before the packaged shaders (tests add their own). The
        attribute ``stage`` is the pixel stage, "fragment" or "compute" (the same bytes:
        :mod:`glsim.backends.gl.plan`): the environment's GLSIM_PIXEL_STAGE if set, else the
        driver's (:func:`~glsim.backends.gl.plan.pixel_stage`); tests and benchmarks set both."""
        self._dots = dots
        self._own_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_context()
        self.fp64 = "GL_ARB_gpu_shader_fp64" in self.ctx.extensions
        self.stage = environment_stage() or pixel_stage(software_renderer(self.ctx))
        self.programs = ProgramCache(self.ctx, shader_dirs)
        self.resources = Resources(self.ctx)
        self._image = reference_image
        self.geometry: GeometryBuffers | None = None  # the mesh's buffers (one mesh at a time)
        self._curved: tuple = (None, {})   # (quadratic mesh, glsim.imaging.quadview.patch_data's cache)
        self._timer: dict[str, float] | None = None   # pass name → seconds, inside pass_times()
        self.last_passes: tuple[str, ...] = ()
        self._steps = {**{k: functools.partial(f, self) for k, f in deform_steps.STEPS.items()},
                       **{k: self._image_pass for k in ("box", "blur", "vignette", "psf", "fpn", "noise", "quantize")}}

    # ---- resources -------------------------------------------------------------------------
    def _reference_texture(self, method: str):
        def make():
            coeffs = pack_pairs(interp.prepare(self._image, method, np.float32))
            tex = self.ctx.texture(coeffs.shape[1::-1], 4, np.ascontiguousarray(coeffs).tobytes(), dtype="f4")
            tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            return tex
        return self.resources.get(("reference", method), make)

    def speckle_binder(self, method: str) -> Callable:
        """What binds the speckle a program samples: procedural.glsl's dots (uploaded once), or
        ``method``'s reference texture on u_ref's unit."""
        if method == "procedural":
            buffers = self.resources.get(("dots",), lambda: dot_buffers(self.ctx, self._dots))
            return functools.partial(bind_dots, buffers)
        tex = self._reference_texture(method)
        return lambda prog: tex.use(_REF_UNIT)

    def dropped_counter(self):
        """Pass 2's count of samples mapping outside the reference (zero at each frame's start)."""
        return self.resources.get(("dropped",), lambda: self.ctx.buffer(bytes(4)))

    def patch_buffers(self, patches, mode: str, fp64: bool):
        """Bindings PATCH_NODES (the patches' local control points at this step) and PATCH_REF (their
        reference data: frame points for exact, image points for q4), made once per step."""
        dt = np.float64 if fp64 else np.float32
        ref = patches.ref_uv if mode == "q4" else patches.ref_xr
        return [self.resources.latest(f"patch_{name}", (key, fp64),
                                      lambda a=array: self.ctx.buffer(np.ascontiguousarray(a, dt).tobytes()))
                for name, key, array in (("local", patches.token, patches.local),
                                         ("ref", (patches.token[0], mode), ref))]

    def _ray_map(self, cam, s: int, kind: str, aperture: float = 1.0):
        """The camera's ray map (:func:`glsim.backends.gl.rays.ray_map`)."""
        self._make_current()
        return ray_map(self.resources, self.programs, cam, s, kind, aperture)

    def close(self) -> None:
        """Release every GL object of this backend (and its context, if it made it)."""
        self._make_current()   # this context's objects, released in it
        self.resources.release()
        if self.geometry is not None:
            self.geometry.release()
            self.geometry = None
        self._curved = (None, {})
        self.programs.release()
        if self._own_ctx:
            self.ctx.release()

    def _make_current(self) -> None:
        """Make this backend's context current on this thread (another context may have been
        made current since, and the programs are shared per context). Left current: EGL's
        "exit" would leave no context current at all."""
        self.ctx.__enter__()

    @contextlib.contextmanager
    def pass_times(self):
        """Time each pass of the renders in the block on its own, the driver finished before and
        after it (yields pass name → seconds, summed; a breakdown, not pipelined wall time)."""
        self._timer = {}
        try:
            yield self._timer
        finally:
            self._timer = None

    @contextlib.contextmanager
    def in_stage(self, stage: str):
        """This backend with the pixel stage ``stage`` inside the block (to compare the two)."""
        saved, self.stage = self.stage, stage
        try:
            yield self
        finally:
            self.stage = saved

    @functools.cached_property
    def capabilities(self) -> Capabilities:
        gl = driver_info(self.ctx)
        return Capabilities(device_geometry=True, float64=self.fp64, passes=True,
                            max_size=min(gl["GL_MAX_TEXTURE_SIZE"], gl["GL_MAX_RENDERBUFFER_SIZE"]),
                            subpixel_bits=gl["GL_SUBPIXEL_BITS"])

    # ---- rendering -------------------------------------------------------------------------
    def _buffers(self, view: ViewSpec) -> GeometryBuffers:
        """The mesh's GL buffers (made when a renderer's mesh is first drawn on this backend)."""
        if self.geometry is None or self.geometry.geo is not view.mesh_geo:
            if self.geometry is not None:
                self.geometry.release()
            self.geometry = GeometryBuffers(self.ctx, self.programs, view.mesh_geo)
        return self.geometry

    def render(self, request: Request) -> Raster:
        """One request (glsim.backends.contract): :meth:`submit`, then :meth:`collect`."""
        return self.collect(self.submit(request))

    def submit(self, request: Request) -> Frame:
        """Execute the request's plan and queue its read-backs; nothing waits for the GPU.
        Curved elements (exact, q4): the view's elements are the quadratic patches' linear
        pieces and each sample is mapped on its curved patch (shaders/quadratic.glsl). With
        truth at s > 1 the plan of the same render at 1 spp runs after it for the raster."""
        view, opts, c, fx = request.view, request.options, request.curved, request.effects
        patches = None
        if c is not None:
            if self._curved[0] is not c.mesh:
                self._curved = (c.mesh, {})
            patches = patch_data(c, view, opts.mode, self._curved[1])
        self._make_current()
        quantize = request.quantize if self.fp64 else None
        s, truth = opts.supersampling, request.truth
        executed: list[str] = []
        st = self._frame(view, opts, truth and s == 1, fx, patches, quantize)
        image, raster, report = self._run(st, executed, warn=True, polish=request.polish)
        if truth and s > 1:
            one = self._frame(view, replace(opts, samples_per_pixel=1), True, _NO_EFFECTS, patches, None)
            raster = self._run(one, executed, warn=False, polish=request.polish, image=False)[1]
        self.last_passes = tuple(executed)
        return Frame(image, raster or (lambda: None), report, stage_names(st.plan, fx), c, view.camera, opts.mode)

    def _frame(self, view: ViewSpec, opts, truth: bool, fx, patches, quantize: int | None) -> FrameState:
        """The state of one plan's execution (its plan made, nothing drawn)."""
        pieces = patches.pieces if patches is not None else None
        p = plan(opts, truth, self.fp64, fx, view.camera, view.ref_camera, pieces, self.stage, bool(quantize))
        geo = self._buffers(view)
        st = FrameState(view, opts, p, opts.supersampling, truth, fx, patches, geo, view_uniforms(view, geo, patches),
                        quantize, blur_setup(fx.optics, fx.sigma_max, self.fp64) if fx.blur else None)
        lit = None if fx.lighting is None else (fx.lighting.normals == "flat", _light_uniforms(fx))
        deform_steps.bindings(self, st, lit)
        return st

    def _run(self, st: FrameState, executed: list, warn: bool, polish: bool, image: bool = True):
        """Execute ``st``'s plan, pass by pass in order, then queue the reads: (the image's
        pending read if ``image``, what makes the raster or None, what reports the view's
        problems)."""
        for ps in st.plan.passes:
            if self._timer is None:
                self._steps[ps.step](st, ps)
            else:
                self._timed(st, ps)
            executed.append(ps.shader)
        check_error(self.ctx, lambda: f"passes {list(executed)}")
        self.ctx.memory_barrier()  # shader storage and image writes visible to the read-backs
        report = queue_report(self.resources.pack, st.view, st.s, st.geo, self.dropped_counter(), warn)
        raster = queue_raster(self.resources, st.view, st.opts.mode, st.color, st.plan, st.patches,
                              polish) if st.truth else None
        grey = st.textures["grey"]
        pending = read_texture(self.resources.pack, grey, _DTYPES[grey.dtype]) if image else None
        self.resources.give_back()
        return pending, raster, report

    def _timed(self, st: FrameState, ps) -> None:
        self.ctx.finish()
        t0 = time.perf_counter()
        self._steps[ps.step](st, ps)
        self.ctx.finish()
        self._timer[ps.shader] = self._timer.get(ps.shader, 0.0) + time.perf_counter() - t0

    def _image_pass(self, st: FrameState, ps) -> None:
        """An image pass of the plan; the box filter after Newton's sub-samples reads the lists
        (the pixels subsamples.frag finished are skipped)."""
        if ps.step == "box" and st.pixels is not None:
            st.geo.bind_lists(*st.size)
        self.image_step(st, ps)

    def collect(self, frame: Frame) -> Raster:
        """Fetch a submitted frame's image (and raster), and warn about its view's problems; the
        raster comes back in the patches' terms for curved elements."""
        self._make_current()
        image = frame.image.fetch(self.resources.pack)
        frame.report()
        raster, c = frame.raster(), frame.curved
        if raster is not None and c is not None:
            raster = pieces_to_patches(raster, c, frame.camera, frame.mode)
        return Raster(image, raster, frame.stages)
