"""backend="gl": rasterize a :class:`~glsim.geometry.View` with OpenGL shaders.

Passes: (1) the deformation pass at s×s samples per pixel into an R32F target (and the truth
maps when asked), with a depth test; (2) for s > 1, a box-filter pass down to W×H.
"""
from __future__ import annotations

import numpy as np

from .. import interp
from ..geometry import View
from .context import check_error, create_context
from .programs import ProgramCache

_CORNER_XE = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], np.float32)
_TRIANGLES = np.array([0, 1, 2, 0, 2, 3], np.int32)


def program_defines(opts, truth: bool, fp64: bool) -> dict:
    """The #defines of the deformation program for these render options."""
    d = {f"MODE_{opts.mode.upper()}": None, f"INTERP_{opts.interpolation.upper()}": None,
         "SS": opts.supersampling}
    if opts.precision == "fp64" and fp64 and opts.mode != "fast":
        d["FP64"] = None
    if truth:
        d["TRUTH"] = None
    return d


def element_data(view: View, mode: str, dtype) -> np.ndarray:
    """Per-element storage-buffer payload: q4 → uv (8), ref uv (8), Z (4); exact → Xd (12), Xr (12)."""
    M = len(view.Xd)
    if mode == "q4":
        parts = [view.uv.reshape(M, 8), view.ref_uv.reshape(M, 8), view.Xd[..., 2]]
    else:
        parts = [view.Xd.reshape(M, 12), view.Xr.reshape(M, 12)]
    return np.ascontiguousarray(np.concatenate(parts, axis=1), dtype=dtype)


class GLBackend:
    """OpenGL renderer over one EGL context (its own, or a shared one passed in)."""
    name = "gl"

    def __init__(self, reference_image: np.ndarray, ctx=None):
        self._own_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_context()
        self.fp64 = "GL_ARB_gpu_shader_fp64" in self.ctx.extensions
        self.programs = ProgramCache(self.ctx)
        self._image = reference_image
        self._textures: dict[str, object] = {}
        self._targets: dict[tuple, tuple] = {}

    # ---- resources -------------------------------------------------------------------------
    def _reference_texture(self, method: str):
        if method not in self._textures:
            coeffs = interp.prepare(self._image, method, np.float32)
            tex = self.ctx.texture(coeffs.shape[::-1], 1, np.ascontiguousarray(coeffs).tobytes(), dtype="f4")
            tex.filter = (self.ctx.NEAREST, self.ctx.NEAREST)
            self._textures[method] = tex
        return self._textures[method]

    def _target(self, width: int, height: int, truth: bool):
        key = (width, height, truth)
        if key not in self._targets:
            ctx = self.ctx
            color = [ctx.texture((width, height), 1, dtype="f4")]
            if truth:
                color += [ctx.texture((width, height), 4, dtype="f4"), ctx.texture((width, height), 4, dtype="f4")]
            depth = ctx.depth_renderbuffer((width, height))
            self._targets[key] = (ctx.framebuffer(color_attachments=color, depth_attachment=depth), color, depth)
        return self._targets[key]

    def _unbind(self) -> None:
        """Bind framebuffer 0 before releasing ours: moderngl re-binds the current framebuffer
        when it creates the next one, which fails (GL_INVALID_OPERATION) if it was deleted."""
        self.ctx.detect_framebuffer(0).use()

    def close(self) -> None:
        self._unbind()
        for fbo, color, depth in self._targets.values():
            fbo.release()
            for t in color:
                t.release()
            depth.release()
        for tex in self._textures.values():
            tex.release()
        self._targets.clear()
        self._textures.clear()
        self.programs.release()
        if self._own_ctx:
            self.ctx.release()

    # ---- rendering -------------------------------------------------------------------------
    @staticmethod
    def _set(prog, name: str, values, fp64: bool) -> None:
        if name in prog:
            prog[name].write(np.asarray(values, dtype="f8" if fp64 else "f4").tobytes())

    def _geometry(self, view: View, mode: str):
        """Vertex data (unshared corners) and the triangle indices of the drawn elements."""
        M = len(view.Xd)
        elem = np.repeat(np.arange(M, dtype=np.int32), 4)
        if mode == "exact":
            b = view.bbox.astype(np.float32)
            drawn = np.flatnonzero(view.bbox[:, 2] >= view.bbox[:, 0])
            px = np.stack([np.stack([b[:, 0] - 0.5, b[:, 1] - 0.5], 1), np.stack([b[:, 2] + 0.5, b[:, 1] - 0.5], 1),
                           np.stack([b[:, 2] + 0.5, b[:, 3] + 0.5], 1), np.stack([b[:, 0] - 0.5, b[:, 3] + 0.5], 1)], 1)
            verts = np.zeros(M * 4, dtype=[("px", "f4", 2), ("elem", "i4")])
            verts["px"] = px.reshape(-1, 2)
            layout = "2f 1i"
            attrs = ("in_px", "in_elem")
        else:
            drawn = np.flatnonzero(view.projectable)
            verts = np.zeros(M * 4, dtype=[("pos", "f4", 3), ("ref", "f4", 2), ("xe", "f4", 2), ("elem", "i4")])
            verts["pos"] = view.Xd.reshape(-1, 3)
            verts["ref"] = view.ref_uv.reshape(-1, 2)
            verts["xe"] = np.tile(_CORNER_XE, (M, 1))
            layout = "3f 2f 2f 1i"
            attrs = ("in_pos", "in_ref", "in_xe", "in_elem")
        verts["elem"] = elem
        index = (drawn[:, None] * 4 + _TRIANGLES[None]).astype(np.int32).ravel()
        return verts, index, layout, attrs

    def render_view(self, view: View, opts, truth: bool = False):
        """Image (H, W) float32 and, if asked, the pixel-centre raster (as the CPU backend)."""
        image = self._pass(view, opts, opts.supersampling, truth and opts.supersampling == 1)
        raster = None
        if truth:
            if opts.supersampling == 1:
                image, raster = image
            else:
                from dataclasses import replace
                _, raster = self._pass(view, replace(opts, samples_per_pixel=1), 1, True)
        return image, raster

    def _pass(self, view: View, opts, s: int, truth: bool):
        ctx = self.ctx
        W, H = view.camera.size
        cam, ref_cam = view.camera, view.ref_camera
        defines = program_defines(opts, truth, self.fp64)
        fp64 = "FP64" in defines
        vert = "exact.vert" if opts.mode == "exact" else "deform.vert"
        prog = self.programs.program(vert, "deform.frag", defines=defines)
        self._set(prog, "u_intr", cam.intrinsics, fp64)
        self._set(prog, "u_dist", cam.distortion.coeffs, fp64)
        self._set(prog, "u_valid_r2", [cam.distortion.valid_radius() ** 2], fp64)
        self._set(prog, "u_ref_intr", ref_cam.intrinsics, fp64)
        self._set(prog, "u_ref_dist", ref_cam.distortion.coeffs, fp64)
        self._set(prog, "u_ref_valid_r2", [ref_cam.distortion.valid_radius() ** 2], fp64)
        for name, value in (("u_size", (float(W), float(H))), ("u_far", float(view.far)),
                            ("u_ref_size", tuple(float(x) for x in ref_cam.size))):
            if name in prog:
                prog[name].value = value
        tex = self._reference_texture(opts.interpolation)
        tex.use(0)
        if "u_ref" in prog:
            prog["u_ref"].value = 0

        verts, index, layout, attrs = self._geometry(view, opts.mode)
        vbo = ctx.buffer(verts.tobytes())
        ibo = ctx.buffer(index.tobytes()) if len(index) else None
        ssbo = None
        if opts.mode != "fast":
            ssbo = ctx.buffer(element_data(view, opts.mode, np.float64 if fp64 else np.float32).tobytes())
            ssbo.bind_to_storage_buffer(0)
        fbo, color, _ = self._target(W * s, H * s, truth)
        fbo.use()
        fbo.viewport = (0, 0, W * s, H * s)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.CULL_FACE)
        fbo.clear(depth=1.0)
        # clear the grey target to the background; truth targets to zero
        color[0].write(np.full((H * s, W * s), opts.background, np.float32).tobytes())
        for t in color[1:]:
            t.write(np.zeros((H * s, W * s, 4), np.float32).tobytes())
        if ibo is not None:
            # attributes the compiled program does not use become padding
            fmt = " ".join(f if a in prog else f"{int(f[:-1]) * 4}x" for f, a in zip(layout.split(), attrs))
            used = [a for a in attrs if a in prog]
            vao = ctx.vertex_array(prog, [(vbo, fmt, *used)], index_buffer=ibo, index_element_size=4)
            vao.render(ctx.TRIANGLES, vertices=len(index))
            vao.release()
        ctx.disable(ctx.DEPTH_TEST)
        check_error(ctx, f"deformation pass ({opts.mode})")
        for b in (vbo, ibo, ssbo):
            if b is not None:
                b.release()

        if s > 1:
            grey = self._downsample(color[0], W, H, s)
        else:
            grey = np.frombuffer(color[0].read(), np.float32).reshape(H, W).copy()
        if not truth:
            return grey
        m = np.frombuffer(color[1].read(), np.float32).reshape(H * W, 4).astype(np.float64)
        x = np.frombuffer(color[2].read(), np.float32).reshape(H * W, 4).astype(np.float64)
        elem = np.rint(x[:, 0]).astype(np.int64) - 1
        raster = {"element": elem, "xi": m[:, 2], "eta": m[:, 3], "ref_uv": m[:, :2] + x[:, 1:3]}
        return grey, raster

    def _downsample(self, samples, W: int, H: int, s: int) -> np.ndarray:
        ctx = self.ctx
        prog = self.programs.program("fullscreen.vert", "downsample.frag", defines={"SS": s})
        out = ctx.texture((W, H), 1, dtype="f4")
        fbo = ctx.framebuffer(color_attachments=[out])
        fbo.use()
        fbo.viewport = (0, 0, W, H)
        samples.use(0)
        prog["u_samples"].value = 0
        vao = ctx.vertex_array(prog, [])
        vao.render(ctx.TRIANGLES, vertices=3)
        grey = np.frombuffer(out.read(), np.float32).reshape(H, W).copy()
        check_error(ctx, "box-filter pass")
        self._unbind()
        for obj in (vao, fbo, out):
            obj.release()
        return grey
