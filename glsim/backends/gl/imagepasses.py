"""The GL backend's image passes: full-screen fragment programs over a texture — box filter,
depth-of-field blur, camera effects, noise, quantisation — drawn into the backend's textures or
scratch textures lent per frame (:class:`ImagePasses`, a part of
:class:`glsim.backends.gl.backend.GLBackend`); each also as a compute pass (the compute pixel
stage: glsim.backends.gl.plan; shaders/comp_pass.glsl). :meth:`ImagePasses.image_step` runs one
plan pass over the frame's named textures.
"""
from __future__ import annotations

import numpy as np

from glsim.effects import noise
from glsim.effects.dof import blur_scheme, kernel_radius, shader_uniforms
from glsim.backends.gl.bindings import image, sampler
from glsim.backends.gl.context import check_error
from glsim.backends.gl.plan import blur_passes
from glsim.backends.gl.readback import read_texture
from glsim.backends.gl.sensor_passes import fpn_uniforms, psf_passes
from glsim.backends.gl.uniforms import set_uniform


_UINT_FORMATS = {"u1": "r8ui", "u2": "r16ui"}   # a compute pass's integer output image, by dtype
_PASS_OUT = (image("PASS_OUT"), image("PASS_OUT_B"))   # a compute pass's outputs


class ImagePasses:
    """Full-screen passes of a GL backend. Expects of the backend: ``ctx``, ``programs``,
    ``fp64``, ``stage`` (the pixel stage) and ``resources`` (:mod:`glsim.backends.gl.resources`)."""

    def fullscreen_pass(self, frag: str, defines: dict, inputs: dict, uniforms: dict, size: tuple[int, int],
                        components: tuple[int, ...] = (1,), into=None, dtype: str = "f4", scratch: list | None = None,
                        compute: bool | None = None):
        """Run a full-screen fragment pass into a new R32F texture of ``size`` (W, H); the
        caller releases it. ``inputs`` maps sampler names to textures or float arrays (H, W)
        (arrays are uploaded for the pass and released after it), each bound to its sampler's
        unit (glsim.backends.gl.bindings.SAMPLERS). ``components``: one texture
        per fragment output with that many components (then a tuple is returned), of moderngl
        ``dtype``. ``into``: an existing texture to draw into instead (pixels the shader
        discards keep their values); it is returned. ``scratch``: the outputs are scratch
        textures lent for the frame (``resources.borrow``), not made and released. ``compute``: as the compute
        pass of the same shader (its .comp file; its outputs images of ``dtype``, two at most);
        by default as the backend's pixel stage (``stage``) has it."""
        ctx = self.ctx
        W, H = size
        compute = self.stage == "compute" if compute is None else compute
        if compute:
            fmt = {"OUT_FORMAT": _UINT_FORMATS[dtype]} if dtype in _UINT_FORMATS else {}   # (quantize.frag's)
            prog = self.programs.compute(frag.replace(".frag", ".comp"), {**defines, **fmt})
        else:
            prog = self.programs.program("fullscreen.vert", frag, defines=defines)
        uploaded = []
        for name, tex in inputs.items():
            if isinstance(tex, np.ndarray):
                a = np.ascontiguousarray(tex, np.float32)
                tex = ctx.texture(a.shape[::-1], 1, a.tobytes(), dtype="f4")
                tex.filter = (ctx.NEAREST, ctx.NEAREST)
                uploaded.append(tex)
            tex.use(sampler(name))
        for name, value in uniforms.items():
            if prog.get(name, None) is not None:
                set_uniform(prog, name, value)
        if into is not None:
            outs, fbo = (into,), self.resources.framebuffer((into,))
        elif scratch:
            outs, fbo, _ = self.resources.borrow((W, H), tuple(components), dtype)
        else:
            outs = tuple(ctx.texture((W, H), n, dtype=dtype) for n in components)
            fbo = ctx.framebuffer(color_attachments=list(outs))
            uploaded.append(fbo)
        if compute:
            for unit, tex in zip(_PASS_OUT, outs):
                tex.bind_to_image(unit, read=False, write=True)
            prog.run((W + 15) // 16, (H + 7) // 8)   # comp_pass.glsl's work groups
            ctx.memory_barrier()   # its image stores seen by the reads and passes after
        else:
            fbo.use()
            fbo.viewport = (0, 0, W, H)
            self.resources.vertex_array(prog).render(ctx.TRIANGLES, vertices=3)
        check_error(ctx, lambda: f"pass {frag} {sorted(defines)}")
        ctx.detect_framebuffer(0).use()   # (before releasing a framebuffer of its own; on llvmpipe it also hands the
        #                  queued pass to the render threads now, which a stream of frames gains from)
        for obj in uploaded:
            obj.release()
        return outs[0] if len(outs) == 1 else outs

    def image_step(self, st, ps) -> None:
        """Run the image pass ``ps`` of a plan on the frame ``st``'s named textures
        (``st.textures``; its outputs replace them), with the defines and uniforms its effect
        asks for."""
        fx, size = st.fx, st.size
        inputs = {sampler_name: st.textures[name] for sampler_name, name in ps.inputs}
        defines, uniforms, components, into, dtype = {}, {}, (1,) * len(ps.outputs), None, "f4"
        if ps.step == "box":
            defines = {"SS": st.s, **({ps.variant: None} if ps.variant else {}),
                       **({"SKIP_DONE": None} if st.pixels is not None else {})}
            into = self._box_target(st, ps.outputs[0])
        elif ps.step == "blur":
            defines, uniforms = st.blur
            defines = {ps.variant: None, **defines}
            components = (4, 4) if ps.variant == "BLUR_ROWS" else components
        elif ps.step == "vignette":
            inputs["u_gain"] = fx.vignette
        elif ps.step == "psf":
            defines, arrays, uniforms = next(x for x in psf_passes(fx.psf) if ps.variant in x[0])
            inputs.update(arrays)
        elif ps.step == "fpn":
            uniforms = fpn_uniforms(fx, size[0])
        elif ps.step == "noise":
            if fx.noise.model == "heteroscedastic":
                inputs["u_variance"] = noise.variance_texture(fx.variance, fx.bit_depth)
            defines = noise.shader_defines(fx.noise)
            uniforms = {**noise.shader_uniforms(fx.noise, fx.bit_depth), "u_seed": int(fx.noise_seed), "u_width": size[0]}
        elif ps.step == "quantize":
            defines, uniforms = {"FP64": None}, {"u_top": float((1 << st.quantize) - 1)}
            dtype = "u1" if st.quantize == 8 else "u2"
            into = self.resources.texture(size, "quantized", dtype=dtype)
        frag = ps.shader.replace(".comp", ".frag")
        out = self.fullscreen_pass(frag, defines, inputs, uniforms, size, components, into=into, dtype=dtype,
                                   scratch=into is None)
        st.textures.update(zip(ps.outputs, out if isinstance(out, tuple) else (out,)))

    def _box_target(self, st, name: str):
        """Where the box filter writes ``name`` ("grey" or "depth"): the Newton pass's W×H
        textures, which it completes, or the backend's own."""
        if st.pixels is not None:
            return st.pixels[0] if name == "grey" else st.pixels[-1]
        return self.resources.texture(st.size, name)

    def blur_passes(self, grey, depth, optics, sigma_max: float, size: tuple[int, int]):
        """The depth-of-field passes of ``optics.scheme`` (glsim.effects.dof.blur_scheme; the
        plan's, :func:`glsim.backends.gl.plan.blur_passes`) on the grey texture (or (H, W)
        array) with its depth; returns the blurred grey texture (lent: ``resources.give_back``)."""
        from types import SimpleNamespace

        st = SimpleNamespace(textures={"grey": grey, "depth": depth}, size=size, fx=None,
                             blur=blur_setup(optics, sigma_max, self.fp64))
        for ps in blur_passes(blur_scheme(optics)):
            self.image_step(st, ps)
        return st.textures["grey"]

    @staticmethod
    def read(tex) -> np.ndarray:
        """An R32F texture as a float32 (H, W) array (read straight into it: no second copy)."""
        W, H = tex.size
        out = np.empty((H, W), np.float32)
        tex.read_into(out)
        return out

    def quantize_pass(self, grey, bit_depth: int) -> np.ndarray:
        """shaders/quantize.frag on an R32F texture or (H, W) array: the image as
        :func:`glsim.io.images.quantize` gives it (uint8, or uint16 for 10–16 bits), read back
        in that type. Needs float64 (``self.fp64``)."""
        dtype = "u1" if bit_depth == 8 else "u2"
        H, W = grey.shape if isinstance(grey, np.ndarray) else grey.size[::-1]
        out = self.fullscreen_pass("quantize.frag", {"FP64": None}, {"u_src": grey},
                                   {"u_top": float((1 << bit_depth) - 1)}, (W, H),
                                   into=self.resources.texture((W, H), "quantized", dtype=dtype), dtype=dtype)
        pack = self.resources.pack
        return read_texture(pack, out, np.uint8 if bit_depth == 8 else np.uint16).fetch(pack)

    def noise_pass(self, grey, params, bit_depth: int, seed: int, table=None):
        """noise.frag on an R32F texture or (H, W) array: grey + σ(grey)·z, the same field as
        :func:`glsim.effects.noise.add_noise` (a new texture: the caller releases it)."""
        inputs = {"u_src": grey}
        if params.model == "heteroscedastic":
            inputs["u_variance"] = noise.variance_texture(table, bit_depth)
        H, W = grey.shape if isinstance(grey, np.ndarray) else grey.size[::-1]
        uniforms = {**noise.shader_uniforms(params, bit_depth), "u_seed": int(seed), "u_width": W}
        return self.fullscreen_pass("noise.frag", noise.shader_defines(params), inputs, uniforms, (W, H))


def blur_setup(optics, sigma_max: float, fp64: bool) -> tuple[dict, dict]:
    """The defines and uniforms every blur pass of ``optics`` shares (FP64: sigma and window in
    double from double uniforms, bit for bit numpy's)."""
    kernel = "disk" if blur_scheme(optics) == "disk" else "gaussian"
    # + 1: a pixel's float32 depth may lie an ulp beyond the corners' float64 range
    radius = int(kernel_radius(sigma_max, kernel)) + 1
    return {"MAX_RADIUS": radius, **({"FP64": None} if fp64 else {})}, shader_uniforms(optics)
