"""backend="gl": render a :class:`~glsim.stages.geometry.ViewSpec` with OpenGL shaders.

The mesh is uploaded once per renderer and the deformed nodes once per load step
(:mod:`glsim.backends.gl.geometry`); per view the CPU sets uniforms and issues a compute
dispatch (modes exact and q4: element records, cover rectangles) and one draw call.

Passes, each only when the scene asks for it: the exact mode's per-camera ray map (cached);
the deformation pass at s×s samples per pixel (reference sampling, lighting, truth maps, depth):
in fast mode the element triangles with a depth test; in exact and q4 the candidate lists
(candidates.comp), their depth layers (classify.frag) and full-screen programs that each run
only on their layer (with ``subsamples = "newton"``, subsamples.frag at W×H first finishes the
pixels it can); for s > 1 the box filter down to W×H (of the pixels not finished); the depth-of-field blur
(separable Gaussian or disk); vignetting, the lens PSF and fixed-pattern noise
(:mod:`glsim.backends.gl.sensor_passes`); the noise pass; then one read-back.
"""
from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from glsim.stages import interp
from glsim.effects import Effects
from glsim.stages import truth
from glsim.stages.geometry import ViewSpec
from glsim.stages.quadview import patch_data, pieces_to_patches
from glsim.backends.contract import Capabilities, Raster, Request
from glsim.stages.view import warn_dropped, warn_problems
from glsim.backends.gl.bindings import image, sampler, storage
from glsim.backends.gl.context import check_error, create_context, driver_info, software_renderer
from glsim.backends.gl.geometry import DRAW_FALLBACK, DRAW_RESOLVE, LAYER_DISPATCH, LAYERS, SHAPE_BYTES, GeometryBuffers
from glsim.backends.gl import timing
from glsim.backends.gl.plan import aperture_literal, environment_stage, pixel_stage, plan
from glsim.backends.gl.imagepasses import ImagePasses
from glsim.backends.gl.programs import ProgramCache
from glsim.backends.gl.readback import PackBuffers, Pending, read_buffer, read_texture
from glsim.backends.gl.uniforms import Uniforms, set_uniform


_REF_UNIT, _RAYS_UNIT = sampler("u_ref"), sampler("u_rays")
_DTYPES = {"f4": np.float32, "u1": np.uint8, "u2": np.uint16}   # moderngl texture dtype → numpy


def _target_images(truth: bool, defines) -> tuple[int, ...]:
    """The image units deform.comp writes the deformation target's textures through, in the
    order of :meth:`GLBackend._target`'s (``truth``: its truth maps)."""
    names = ["GREY", *(["MAP", "EXTRA"] if truth else []), *(["LO"] if "TRUTH_LO" in defines else []),
             *(["DEPTH"] if "DEPTH_OUT" in defines else [])]
    return tuple(image(n) for n in names)


def _ray_key(cam, s: int, kind: str, aperture: float = 1.0) -> tuple:
    """The ray map cache's key: the camera model, supersampling, kind and the samples' aperture
    (√ fill factor) (GLBackend._ray_map)."""
    return cam.size, cam.intrinsic_values, cam.distortion, s, kind, aperture


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


_NO_EFFECTS = Effects()


class Frame(NamedTuple):
    """A request submitted to the GPU with its read-backs queued (:meth:`GLBackend.submit`);
    :meth:`GLBackend.collect` fetches them (a tuple: made per image, in fewer steps than a
    frozen dataclass)."""
    image: Pending
    raster: Callable[[], dict | None]       # the truth raster, fetched and finished (None: not asked)
    report: Callable[[], None]              # the view's warnings, from its fetched problem flags
    stages: tuple[str, ...]
    curved: object = None                   # the request's Curved (the raster is mapped to its patches)
    camera: object = None
    mode: str = "exact"


class GLBackend(ImagePasses):
    """OpenGL renderer over one EGL context (its own, or a shared one passed in).

    A request is submitted (every pass queued, every read-back queued into a pixel-pack buffer:
    :mod:`glsim.backends.gl.readback`) and collected (the reads mapped); ``render`` does both.
    Pipelined callers (``Renderer.render_many``) submit the next request before collecting one.
    Targets, scratch textures of the full-screen passes, their framebuffers and vertex arrays,
    and the pack buffers are made once and reused, so a stream of frames allocates nothing."""
    name = "gl"

    def __init__(self, reference_image: np.ndarray, ctx=None, shader_dirs: tuple = (), dots=None):
        """``dots``: the generator's speckle, for ``interpolation = "procedural"``;
        ``shader_dirs`` are searched before the packaged shaders (tests add their own). The
        attribute ``stage`` is the pixel stage, "fragment" or "compute" (the same bytes:
        :mod:`glsim.backends.gl.plan`): the environment's GLSIM_PIXEL_STAGE if set, else the
        driver's (:func:`~glsim.backends.gl.plan.pixel_stage`); tests and benchmarks set both."""
        self._dots = dots
        self._dot_buffers = None
        self._own_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_context()
        self.fp64 = "GL_ARB_gpu_shader_fp64" in self.ctx.extensions
        self.stage = environment_stage() or pixel_stage(software_renderer(self.ctx))
        self.programs = ProgramCache(self.ctx, shader_dirs)
        self._image = reference_image
        self._textures: dict[str, object] = {}
        self._targets: dict[tuple, tuple] = {}
        self._rays: dict[tuple, object] = {}
        self._curved: tuple = (None, {})          # (quadratic mesh, glsim.stages.quadview.patch_data's cache)
        self._patch_cache: dict[tuple, object] = {}   # the patches' GL buffers (_patch_buffers)
        self.geometry: GeometryBuffers | None = None  # the mesh's buffers (one mesh at a time)
        self._pack = PackBuffers(self.ctx)
        self._scratch: dict[tuple, list] = {}   # free (textures, framebuffer) of full-screen passes by shape
        self._lent: dict[int, tuple] = {}       # id(texture) → its scratch entry while a frame uses it
        self._outputs: dict[tuple, object] = {}  # the pixel passes' textures by size and role (_output)
        self._fbos: dict[int, tuple] = {}       # id(texture) → (texture, framebuffer) drawing into it
        self._vaos: dict[int, tuple] = {}       # id(program) → (program, attribute-less vertex array)
        self._ray_host: dict[tuple, np.ndarray] = {}   # the float64 ray maps' bits on the host (truth polish)
        self._dropped = None                    # deform.frag's count of samples mapping outside the reference
        self._visibility = None                 # mode fast's triangle-index target, compute stage (_visibility_target)

    # ---- resources -------------------------------------------------------------------------
    def _reference_texture(self, method: str):
        if method not in self._textures:
            coeffs = pack_pairs(interp.prepare(self._image, method, np.float32))
            tex = self.ctx.texture(coeffs.shape[1::-1], 4, np.ascontiguousarray(coeffs).tobytes(), dtype="f4")
            tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            self._textures[method] = tex
        return self._textures[method]

    def _target(self, width: int, height: int, truth: bool, lo: bool, depth_out: bool):
        """Cached deformation-pass framebuffer: grey, truth maps (if asked) and the low halves
        of (ξ, η) (if ``lo``), depth Z (if asked)."""
        key = (width, height, truth, lo, depth_out)
        if key not in self._targets:
            ctx = self.ctx
            color = [ctx.texture((width, height), 1, dtype="f4")]
            if truth:
                color += [ctx.texture((width, height), 4, dtype="f4"), ctx.texture((width, height), 4, dtype="f4")]
            if lo:
                color.append(ctx.texture((width, height), 2, dtype="f4"))
            if depth_out:
                color.append(ctx.texture((width, height), 1, dtype="f4"))
            depth = ctx.depth_renderbuffer((width, height))
            # the grey target alone, to clear it to the background grey (the others clear to 0);
            # the depth buffer alone, for classify.frag's layers
            grey_only = ctx.framebuffer(color_attachments=color[:1])
            self._targets[key] = (ctx.framebuffer(color_attachments=color, depth_attachment=depth), color, depth,
                                  grey_only, ctx.framebuffer(depth_attachment=depth))
        return self._targets[key]

    def _unbind(self) -> None:
        """Bind framebuffer 0 before releasing ours: moderngl re-binds the current framebuffer
        when it creates the next one, which fails (GL_INVALID_OPERATION) if it was deleted."""
        self.ctx.detect_framebuffer(0).use()

    def close(self) -> None:
        self._make_current()   # this context's objects, released in it
        self._unbind()
        for fbo, color, depth, grey_only, depth_only in self._targets.values():
            fbo.release()
            grey_only.release()
            depth_only.release()
            for t in color:
                t.release()
            depth.release()
        for tex in (*self._textures.values(), *self._rays.values(), *self._outputs.values(),
                    *(self._dot_buffers or ())[:2]):
            tex.release()
        self._dot_buffers = None
        for buf in self._patch_cache.values():
            buf.release()
        self._patch_cache.clear()
        for tex, fbo in self._fbos.values():
            fbo.release()
        entries = [e for free in self._scratch.values() for e in free] + list(self._lent.values())
        for textures, fbo, _ in {id(e): e for e in entries}.values():
            fbo.release()
            for t in textures:
                t.release()
        for _, vao in self._vaos.values():
            vao.release()
        for obj in (self._pack, self._dropped, *(self._visibility or ())[1:]):
            if obj is not None:
                obj.release()
        self._visibility = None
        self._fbos.clear()
        self._outputs.clear()
        self._scratch.clear()
        self._lent.clear()
        self._vaos.clear()
        self._ray_host.clear()
        self._dropped = None
        self._curved = (None, {})
        self._targets.clear()
        self._textures.clear()
        self._rays.clear()
        if self.geometry is not None:
            self.geometry.release()
            self.geometry = None
        self.programs.release()
        if self._own_ctx:
            self.ctx.release()

    def _make_current(self) -> None:
        """Make this backend's context current on this thread (another context may have been
        made current since, and the programs are shared per context). Left current: EGL's
        "exit" would leave no context current at all."""
        self.ctx.__enter__()

    def pass_times(self):
        """A context manager timing each pass of the renders in its block on its own
        (:func:`glsim.backends.gl.timing.pass_times`; named by their shader files)."""
        return timing.pass_times(self.ctx, self.programs.name_of)

    # ---- rendering -------------------------------------------------------------------------
    def _buffers(self, view: ViewSpec) -> GeometryBuffers:
        """The mesh's GL buffers (made when a renderer's mesh is first drawn on this backend)."""
        if self.geometry is None or self.geometry.geo is not view.mesh_geo:
            if self.geometry is not None:
                self.geometry.release()
            self.geometry = GeometryBuffers(self.ctx, self.programs, view.mesh_geo)
        return self.geometry

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

    def render(self, request: Request) -> Raster:
        """One request (glsim.backends.contract): :meth:`submit`, then :meth:`collect`."""
        return self.collect(self.submit(request))

    def submit(self, request: Request) -> Frame:
        """Queue every pass of one request and its read-backs; nothing waits for the GPU except,
        in modes exact and q4, the 8-byte read of whether pass 2 needs its resolve and fallback
        programs. Curved elements (exact, q4): the view's elements are the quadratic patches'
        linear pieces and each sample is mapped on its curved patch (shaders/quadratic.glsl)."""
        v, opts, c = request.view, request.options, request.curved
        patches = None
        if c is not None:
            if self._curved[0] is not c.mesh:
                self._curved = (c.mesh, {})
            patches = patch_data(c, v, opts.mode, self._curved[1])
        self._make_current()
        return self._render_view(v, opts, request.truth, request.effects, patches,
                                 request.quantize if self.fp64 else None, c, request.polish)

    def collect(self, frame: Frame) -> Raster:
        """Fetch a submitted frame's image (and raster), and warn about its view's problems; the
        raster comes back in the patches' terms for curved elements."""
        self._make_current()
        image = frame.image.fetch(self._pack)
        frame.report()
        raster, c = frame.raster(), frame.curved
        if raster is not None and c is not None:
            raster = pieces_to_patches(raster, c, frame.camera, frame.mode)
        return Raster(image, raster, frame.stages)

    def _render_view(self, view: ViewSpec, opts, truth: bool, fx, patches, quantize: int | None = None,
                     curved=None, polish: bool = True) -> Frame:
        s = opts.supersampling
        W, H = view.camera.size
        pieces = patches.pieces if patches is not None else None
        p = plan(opts, truth and s == 1, self.fp64, fx, view.camera, view.ref_camera, pieces, self.stage)
        color, grey, depth, raster, report = self._deform(view, opts, p, s, truth and s == 1, fx, patches, quantize,
                                                          polish=polish)
        stages = ["raster", "interpolate"] + (["light"] if fx.lighting is not None else [])   # one pass
        if p.subsamples:
            stages.append("subsamples")
        elif s > 1:
            stages.append("downsample")
        temps: list = []
        if fx.blur:
            grey = self.blur_passes(grey, depth, fx.optics, fx.sigma_max, (W, H), temps, stages)
        grey = self.camera_passes(grey, fx, (W, H), temps, stages)
        if fx.noise is not None:
            grey = self.noise_pass(grey, fx.noise, fx.bit_depth, fx.noise_seed, fx.variance, scratch=temps)
            stages.append("noise")
        if quantize and p.image_effects:
            grey = self._quantized(grey, quantize)
        image = read_texture(self._pack, grey, _DTYPES[grey.dtype])
        self._recycle(temps)
        if truth and s > 1:
            one = replace(opts, samples_per_pixel=1)
            p1 = plan(one, True, self.fp64, _NO_EFFECTS, view.camera, view.ref_camera, pieces, self.stage)
            raster = self._deform(view, one, p1, 1, True, _NO_EFFECTS, patches, warn=False, polish=polish)[3]
        return Frame(image, raster or (lambda: None), report, tuple(stages), curved, view.camera, opts.mode)

    def _deform(self, view: ViewSpec, opts, p, s: int, truth: bool, fx, patches, quantize: int | None = None,
                warn: bool = True, polish: bool = True):
        """The deformation pass of plan ``p`` into the cached target, then the pixels' box filter
        (s > 1, no Newton sub-samples) and, if no image effects come between, the quantisation
        to ``quantize`` bits, into cached textures (replayed where a view of this camera was
        rendered so before: :mod:`glsim.backends.gl.replay`; what differs between the views of a
        camera goes through the :class:`ViewSlot`). Returns the color textures, the grey and
        depth textures at pixel size (depth if blurred), what finishes the raster (if
        ``truth``; its reads queued; ``polish``: Request.polish) and what reports the view's
        problems (its flags copied on the GPU; nothing if not ``warn``)."""
        geo = self._buffers(view)
        lit = None if fx.lighting is None else (fx.lighting.normals == "flat", _light_uniforms(fx))
        quantize = None if p.image_effects else quantize
        uniforms = self._view_uniforms(view, geo, patches)
        color = self._deform_passes(view, opts, s, truth, p, geo, patches, lit, fx.aperture, uniforms)
        grey, depth = self._pixel_passes(color, view.camera.size, s, p, quantize)
        if opts.mode != "fast":
            geo.view_passes += 1
        check_error(self.ctx, f"deformation pass ({opts.mode})")
        self.ctx.memory_barrier()  # shader storage writes visible to the read-backs
        report = self._queue_report(view, s, geo, warn)
        raster = self._queue_raster(view, opts.mode, color, p, patches, polish) if truth else None
        return color, grey, depth, raster, report

    def _pixel_passes(self, color, size: tuple[int, int], s: int, p, quantize: int | None):
        """The grey and depth (if DEPTH_OUT) textures at pixel size from the deformation pass's
        ``color``: box-filtered at s > 1 unless Newton sub-samples did it, then quantised to
        ``quantize`` bits if given."""
        grey, depth = color[0], (color[-1] if "DEPTH_OUT" in p.define_dict else None)
        if s > 1 and not p.subsamples:
            grey, depth = self._downsample(grey, depth, *size, s)
        if quantize:
            grey = self._quantized(grey, quantize)
        return grey, depth

    def _deform_passes(self, view: ViewSpec, opts, s: int, truth: bool, p, geo, patches, lit, aperture: float,
                       uniforms):
        """The deformation pass's GL commands (what a replay repeats: everything they depend on
        is an argument — ``lit``: (flat normals, the lights' uniforms) or None; ``aperture``:
        √ fill factor —, cached with the objects they name, or the view's own in ``self._slot``);
        returns the color textures."""
        W, H = view.camera.size
        bind, setup = self._deform_bindings(view, opts, s, lit, aperture, patches, p, geo, uniforms)
        if opts.mode != "fast":   # pass 1: element records, covers, the candidate lists
            grow = 0.5 - 0.5 / s
            if p.camera_local:
                geo.view_pass(view, uniforms, opts.mode, True, grow, local=True)
            else:
                geo.view_pass(view, uniforms, opts.mode, "FP64" in p.define_dict, grow=grow)
            geo.candidates_pass(W, H, s)
        bind()
        pixels = self._newton_pixels(view, opts, p, geo, setup) if p.subsamples else None
        color = self._deform_samples(view, opts, s, truth, p, geo, setup)
        if pixels is not None:  # the pixels not done by Newton: the box filter of their samples
            geo.bind_lists(W, H)
            self._downsample(color[0], color[-1] if "DEPTH_OUT" in p.define_dict else None, W, H, s, into=pixels)
            color = pixels
        return color

    def _deform_bindings(self, view: ViewSpec, opts, s: int, lit, aperture: float, patches, p, geo, uniforms):
        """What the deformation programs read: ``bind()`` (the storage buffers of pass 2, bound
        once before it: pass 1 may bind the float64 nodes at the same points) and
        ``setup(prog)`` (the textures and uniforms of deform.frag and its vertex shaders: the
        view's and its camera's, ``self._slot``'s). The values are made once per view and
        camera; every uniform is written on every use: programs are shared per context, so a
        value left by another renderer (a quadratic mesh's sag) must not carry over."""
        cam = view.camera
        fp64 = "FP64" in p.define_dict
        dropped = self._dropped_counter()
        # lit: the lights' uniforms; the step's world-frame corner normals are the slot's
        # (uploaded once per step, rotated in deform.frag)
        lighting = Uniforms(lit[1]) if lit is not None else None
        ref_storage = None
        if p.ref is not None:
            local = p.ref == "REF_LOCAL"
            ref_storage = (geo.ref_local_buffer if local else geo.ref_pinhole_buffer)(view.ref_camera.intrinsic_values)
        textures = self._dots_or_reference(opts.interpolation)
        rays = self._ray_map(cam, s, p.rays, aperture) if p.rays is not None else None

        def bind():
            geo.bind_mesh(fp64)
            geo.bind_step(view, fp64)
            if ref_storage is not None:
                ref_storage.bind_to_storage_buffer(storage(p.ref))
            dropped.bind_to_storage_buffer(storage("DROPPED"))
            if patches is not None:
                for name, buf in zip(("PATCH_NODES", "PATCH_REF"), self._patch_buffers(patches, opts.mode, fp64)):
                    buf.bind_to_storage_buffer(storage(name))
            if lighting is not None:
                geo.normals(view, lit[0]).bind_to_storage_buffer(storage("NORMALS"))

        def setup(prog):
            uniforms.write(prog)
            if lighting is not None:
                lighting.write(prog)
            textures(prog)
            if rays is not None:
                rays.use(_RAYS_UNIT)

        return bind, setup

    @staticmethod
    def _view_uniforms(view: ViewSpec, geo, patches) -> Uniforms:
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

    def _list_program(self, view: ViewSpec, frag: str, defines: dict, setup, geo, target, layer: float,
                      textures=None, uniforms=None, indirect: int | None = None) -> None:
        """One full-screen program of pass 2 (lists.vert at window depth ``layer``, early depth
        tests) into ``target``; ``indirect``: drawn by that command of pass 1's draws (only where
        pass 1 found work for it)."""
        W, H = view.camera.size
        prog = self.programs.program("lists.vert", frag, defines={**defines, "EARLY_TESTS": None})
        setup(prog)
        geo.bind_lists(W, H, textures=True)
        for name, tex in (textures or {}).items():
            tex.use(sampler(name))
        for name, value in {**(uniforms or {}), "u_layer": layer}.items():
            set_uniform(prog, name, value)
        target.use()
        if indirect is None:
            self._vao(prog).render(self.ctx.TRIANGLES, vertices=3)
        else:
            self._vao(prog).render_indirect(geo.draws(W, H), self.ctx.TRIANGLES, count=1, first=indirect)

    def _newton_pixels(self, view: ViewSpec, opts, p, geo, setup):
        """Pass 2a at W×H: the single-candidate pixels done from their centre by Newton
        (subsamples.frag); returns the W×H color textures the box filter then completes."""
        ctx, (W, H) = self.ctx, view.camera.size
        fbo, color, _, grey, depth = self._target(W, H, False, False, "DEPTH_OUT" in p.define_dict)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        grey.clear(opts.background, 0.0, 0.0, 0.0)
        ctx.enable(ctx.DEPTH_TEST)
        geo.classify_pass(depth, W, H, 1)
        ctx.depth_func, fbo.depth_mask = "==", False
        self._list_program(view, "subsamples.frag", p.define_dict, setup, geo, fbo, LAYERS["deform.frag"],
                           {"u_centre_rays": self._ray_map(view.camera, 1, p.rays)},
                           {"u_background": float(opts.background)})
        ctx.depth_func, fbo.depth_mask = "<", True
        ctx.memory_barrier()   # its LIST_DONE marks seen by the passes below
        return color

    def _deform_samples(self, view: ViewSpec, opts, s: int, truth: bool, p, geo, setup):
        """Pass 2 at s×s samples per pixel into the cached target (grey from the background,
        truth and depth from zero): fast mode's element triangles, else the full-screen programs
        on their layers (one candidate, then several) and the overflow fallback's covers — those
        two drawn by pass 1's indirect commands, so nothing waits for the host to decide; with
        the compute pixel stage the first two as compute passes over classify.comp's lists,
        dispatched indirectly alike."""
        ctx, (W, H) = self.ctx, view.camera.size
        defines = p.define_dict
        fbo, color, _, grey, depth = self._target(W * s, H * s, truth, "TRUTH_LO" in defines, "DEPTH_OUT" in defines)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        grey.clear(opts.background, 0.0, 0.0, 0.0)
        fbo.use()
        fbo.viewport = (0, 0, W * s, H * s)
        ctx.disable(ctx.CULL_FACE)
        if opts.mode == "fast" and p.stage == "compute":
            self._fast_compute(defines, setup, geo, W * s, H * s, truth, color)
        elif opts.mode == "fast":  # the element triangles, projected in the vertex stage
            prog = self.programs.program("deform.vert", "deform.frag", defines=defines, geometry="fast.geom")
            setup(prog)
            ctx.enable(ctx.DEPTH_TEST)
            geo.draw(prog)
        elif p.stage == "compute":
            lists = geo.layer_pass(W, H, s)
            geo.bind_lists(W, H, textures=True)
            for unit, tex in zip(_target_images(truth, defines), color):
                tex.bind_to_image(unit, read=False, write=True)
            for name, offset in LAYER_DISPATCH.items():
                prog = self.programs.compute(name, defines)
                setup(prog)
                prog.run_indirect(lists, offset)
            ctx.memory_barrier()   # the image stores seen by the fallback's draws and the passes after
        else:
            ctx.enable(ctx.DEPTH_TEST)
            geo.classify_pass(depth, W, H, s)
            ctx.depth_func, fbo.depth_mask = "==", False
            self._list_program(view, "deform.frag", defines, setup, geo, fbo, LAYERS["deform.frag"])
            self._list_program(view, "resolve.frag", defines, setup, geo, fbo, LAYERS["resolve.frag"],
                               indirect=DRAW_RESOLVE)
            ctx.depth_func, fbo.depth_mask = "<", True
        if opts.mode != "fast":
            # pixels with more candidates than the lists hold: the cover rectangles
            prog = self.programs.program("exact.vert", "deform.frag", defines={**defines, "FALLBACK": None})
            setup(prog)
            geo.bind_lists(W, H, textures=True)
            ctx.enable(ctx.DEPTH_TEST)
            geo.draw(prog, (geo.draws(W, H), DRAW_FALLBACK))
        ctx.disable(ctx.DEPTH_TEST)
        return color

    def _fast_compute(self, defines, setup, geo, w: int, h: int, truth: bool, color) -> None:
        """Mode fast in the compute pixel stage: the element triangles drawn as in the fragment
        stage (the same depth test and discards) into a w×h target of triangle indices, fast.geom
        keeping their records (FAST_VISIBILITY), then deform.comp shading every sample of
        ``color`` from its triangle's record."""
        ctx = self.ctx
        fbo, ids = self._visibility_target(w, h)
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)   # (index 0: no triangle)
        fbo.use()
        fbo.viewport = (0, 0, w, h)
        records = geo.fast_records()
        records.bind_to_storage_buffer(storage("FAST_TRIANGLES"))
        prog = self.programs.program("deform.vert", "deform.frag", defines={**defines, "FAST_VISIBILITY": None},
                                     geometry="fast.geom")
        setup(prog)
        ctx.enable(ctx.DEPTH_TEST)
        geo.draw(prog)
        ctx.disable(ctx.DEPTH_TEST)
        ctx.memory_barrier()   # the records and indices seen by the compute pass
        comp = self.programs.compute("deform.comp", defines)
        setup(comp)
        ids.use(sampler("u_visibility"))
        for unit, tex in zip(_target_images(truth, defines), color):
            tex.bind_to_image(unit, read=False, write=True)
        comp.run((w + 15) // 16, (h + 7) // 8)   # deform.frag's work groups in mode fast
        ctx.memory_barrier()

    def _visibility_target(self, w: int, h: int):
        """The framebuffer of mode fast's triangle indices (R32UI, with a depth buffer) at w×h,
        made once per size (the last one kept)."""
        hit = self._visibility
        if hit is None or hit[0] != (w, h):
            if hit is not None:
                for obj in hit[1:]:
                    obj.release()
            ids = self.ctx.texture((w, h), 1, dtype="u4")
            depth = self.ctx.depth_renderbuffer((w, h))
            hit = self._visibility = ((w, h), self.ctx.framebuffer(color_attachments=[ids], depth_attachment=depth),
                                      ids, depth)
        return hit[1], hit[2]

    def _queue_report(self, view: ViewSpec, s: int, geo, warn: bool):
        """Copy the view's problem flags, dropped count and its step's shape filter on the GPU
        (read when the frame is collected), clear them for the next view; returns what warns
        about them (nothing if not ``warn``)."""
        flags, size = geo.status()
        dropped = self._dropped_counter()
        status = read_buffer(self._pack, [(flags, size), (dropped, 4), (geo.shape_buffer(view), SHAPE_BYTES)]) \
            if warn else None
        geo.clear_status()     # (after the copy above: the GL orders them)
        dropped.write(bytes(4))
        cam = view.camera

        def report():
            if status is None:
                return
            b = status.fetch(self._pack).tobytes()
            problems = geo.problems(view, b[:size], b[size + 4:])
            if problems:
                warn_problems(cam, problems, view.mesh_geo.labels, stacklevel=5)
            warn_dropped(cam, int(np.frombuffer(b[size:size + 4], np.uint32)[0]), s)
        return report

    def _queue_raster(self, view: ViewSpec, mode: str, color, p, patches, polish: bool = True):
        """Queue the truth targets' reads; returns what makes the raster from them: float32 hi
        (+ lo with TRUTH_LO: (ξ, η) to 2^-48) widened to float64, polished where the shader
        computed in float32 and ``polish`` (the patches' (ξ, η) are polished by the caller,
        glsim.render)."""
        W, H = view.camera.size
        lo = "TRUTH_LO" in p.define_dict
        reads = [read_texture(self._pack, t, np.float32) for t in color[1:4 if lo else 3]]

        def raster() -> dict:
            m, x, *low = (r.fetch(self._pack).reshape(H * W, -1) for r in reads)   # each widened once
            out = {"element": np.rint(x[:, 0]).astype(np.int64) - 1, "xi": m[:, 2].astype(np.float64),
                   "eta": m[:, 3].astype(np.float64), "ref_uv": m[:, :2].astype(np.float64) + x[:, 1:3]}
            if low:
                out["xi"] += low[0][:, 0]
                out["eta"] += low[0][:, 1]
                return out
            if patches is not None or not polish:
                return out
            return self._float64_truth(view, mode, out, "FP64" in p.define_dict)
        return raster

    def _patch_buffers(self, patches, mode: str, fp64: bool):
        """Bindings PATCH_NODES (the patches' local control points at this step) and PATCH_REF (their reference
        data: frame points for exact, image points for q4), made once per step / renderer."""
        cache = self._patch_cache
        dt = np.float64 if fp64 else np.float32
        out = []
        for name, key, array in (("local", patches.token, patches.local),
                                 ("ref", (patches.token[0], mode), patches.ref_uv if mode == "q4" else patches.ref_xr)):
            k = (name, key, fp64)
            if k not in cache:
                old = [c for c in cache if c[0] == name]
                for c in old[:-1]:          # keep the last one of each kind besides the new one
                    cache.pop(c).release()
                cache[k] = self.ctx.buffer(np.ascontiguousarray(array, dt).tobytes())
            out.append(cache[k])
        return out

    def _float64_truth(self, view: ViewSpec, mode: str, raster: dict, fp64: bool) -> dict:
        """The raster with float64 (ξ, η) (glsim.stages.truth.polish) from the float32 ones read
        back, over the covered elements' numpy view only; exact mode polishes on the float64
        rays the shader used (the ray map, bit for bit) where it has them."""
        hit = raster["element"] >= 0
        if not hit.any():
            return raster
        W, H = view.camera.size
        elements, local = np.unique(raster["element"][hit], return_inverse=True)
        sub = np.full(len(hit), -1, np.int64)
        sub[hit] = local
        key = _ray_key(view.camera, 1, "bits")
        if mode == "exact" and fp64 and key in self._rays and key not in self._ray_host:
            self._ray_host[key] = np.frombuffer(self._rays[key].read(), np.float64).reshape(H * W, 2)
        xn = self._ray_host.get(key) if mode == "exact" and fp64 else None
        out = truth.polish(view.subset(elements), mode, dict(raster, element=sub), xn)
        out["element"] = raster["element"]
        return out

    def _dots_or_reference(self, method: str) -> Callable:
        """What binds the speckle a program samples: procedural.glsl's dots, or ``method``'s
        reference texture on u_ref's unit."""
        if method == "procedural":
            return self._bind_dots
        tex = self._reference_texture(method)

        def bind(prog):
            tex.use(_REF_UNIT)
        return bind

    def _bind_dots(self, prog) -> None:
        """Bind procedural.glsl's storage buffers (made once) and set its uniforms."""
        if self._dot_buffers is None:
            from glsim.stages.reference import require_dots
            from glsim.scene.speckle import dot_grid

            dots = require_dots(self._dots)
            grid = dot_grid(dots)
            c = dots.centres[grid.order]
            corner = np.asarray(grid.origin) + np.floor((c - grid.origin) / grid.cell) * grid.cell
            dot_data = np.column_stack([c - corner, dots.radii[grid.order]]).astype(np.float32)
            cell_data = np.column_stack([grid.start, grid.count]).astype(np.int32)
            hi = np.asarray(grid.origin, np.float32)
            uniforms = {"u_grid_origin_hi": tuple(hi.tolist()),
                        "u_grid_origin_lo": tuple((np.asarray(grid.origin) - hi).tolist()),
                        "u_grid_cell": grid.cell, "u_grid_dims": grid.dims, "u_dot_edge": dots.edge_px,
                        "u_dot_black": dots.black, "u_dot_white": dots.white}
            self._dot_buffers = (self.ctx.buffer(dot_data.tobytes() or bytes(12)),
                                 self.ctx.buffer(cell_data.tobytes()), Uniforms(uniforms))
        dot_buf, cell_buf, uniforms = self._dot_buffers
        dot_buf.bind_to_storage_buffer(storage("DOTS"))
        cell_buf.bind_to_storage_buffer(storage("DOT_CELLS"))
        uniforms.write(prog)

    def _ray_map(self, cam, s: int, kind: str, aperture: float = 1.0):
        """Cached per camera model, supersampling, ``kind`` and ``aperture`` (shaders/rays.frag):
        (W·s)×(H·s) undistorted rays, "bits" as float64 pairs (RGBA32UI), "split" as float32 hi + lo
        made in float64, "float" in float32 (RGBA32F); ``aperture`` < 1 (√ of the sensor's fill
        factor) scales the samples' offsets from their pixel centres (at s = 1: the centres)."""
        aperture = aperture if s > 1 else 1.0
        key = _ray_key(cam, s, kind, aperture)
        out = self._rays.get(key)
        if out is None:
            W, H = cam.size
            fp64 = kind != "float"
            defines = {"SS": s, **({"FP64": None} if fp64 else {}),
                       **({"RAY_BITS": None} if kind == "bits" else {"RAY_SPLIT": None} if kind == "split" else {}),
                       **({"APERTURE": aperture_literal(aperture, fp64)} if aperture != 1.0 else {})}
            prog = self.programs.program("fullscreen.vert", "rays.frag", defines=defines)
            Uniforms({"u_intr": cam.intrinsics, "u_dist": cam.distortion.coeffs,
                      "u_valid_r2": cam.distortion.valid_radius() ** 2}).write(prog)
            out = self.ctx.texture((W * s, H * s), 4, dtype="u4" if kind == "bits" else "f4")
            out.filter = (self.ctx.NEAREST, self.ctx.NEAREST)   # (an integer texture must not filter)
            fbo = self.ctx.framebuffer(color_attachments=[out])
            fbo.use()
            fbo.viewport = (0, 0, W * s, H * s)
            vao = self.ctx.vertex_array(prog, [])
            vao.render(self.ctx.TRIANGLES, vertices=3)
            check_error(self.ctx, "ray map")
            self._unbind()
            vao.release()
            fbo.release()
            self._rays[key] = out
        return out

    def _dropped_counter(self):
        """deform.frag's count of samples mapping outside the reference (zero at each frame's start)."""
        if self._dropped is None:
            self._dropped = self.ctx.buffer(bytes(4))
        return self._dropped
