"""The GL backend's image passes: full-screen fragment programs over a texture — box filter,
depth-of-field blur, camera effects, noise, quantisation — drawn into scratch textures reused
across frames (:class:`ImagePasses`, a part of :class:`glsim.backends.gl.backend.GLBackend`);
each also as a compute pass (the compute pixel stage: glsim.backends.gl.plan;
shaders/pixelpass.glsl).
"""
from __future__ import annotations

import numpy as np

from glsim.effects import noise
from glsim.effects.dof import blur_scheme, kernel_radius, shader_uniforms
from glsim.backends.gl.bindings import image, sampler
from glsim.backends.gl.context import check_error
from glsim.backends.gl.plan import BLUR_PASSES
from glsim.backends.gl.readback import read_texture
from glsim.backends.gl.sensor_passes import camera_passes
from glsim.backends.gl.uniforms import set_uniform


_UINT_FORMATS = {"u1": "r8ui", "u2": "r16ui"}   # a compute pass's integer output image, by dtype
_PASS_OUT = (image("PASS_OUT"), image("PASS_OUT_B"))   # a compute pass's outputs


class ImagePasses:
    """Full-screen passes of a GL backend. Expects of the backend: ``ctx``, ``programs``,
    ``fp64``, ``stage`` (the pixel stage), ``_pack`` (pack buffers), ``_unbind()``, and the
    reuse tables ``_scratch`` (free scratch textures by shape), ``_lent`` (those a frame
    holds), ``_outputs``, ``_fbos`` and ``_vaos``."""

    def fullscreen_pass(self, frag: str, defines: dict, inputs: dict, uniforms: dict, size: tuple[int, int],
                        components: tuple[int, ...] = (1,), into=None, dtype: str = "f4", scratch: list | None = None,
                        compute: bool | None = None):
        """Run a full-screen fragment pass into a new R32F texture of ``size`` (W, H); the
        caller releases it. ``inputs`` maps sampler names to textures or float arrays (H, W)
        (arrays are uploaded for the pass and released after it), each bound to its sampler's
        unit (glsim.backends.gl.bindings.SAMPLERS). ``components``: one texture
        per fragment output with that many components (then a tuple is returned), of moderngl
        ``dtype``. ``into``: an existing texture to draw into instead (pixels the shader
        discards keep their values); it is returned. ``scratch``: a frame's list of textures
        on loan: the outputs are taken from the backend's reused ones and added to it
        (:meth:`_recycle` gives them back), not made and released. ``compute``: as the compute
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
            outs, fbo = (into,), self._framebuffer_into(into)
        elif scratch is not None:
            outs, fbo, _ = self._borrow((W, H), tuple(components), dtype)
            scratch.extend(outs)
        else:
            outs = tuple(ctx.texture((W, H), n, dtype=dtype) for n in components)
            fbo = ctx.framebuffer(color_attachments=list(outs))
            uploaded.append(fbo)
        if compute:
            for unit, tex in zip(_PASS_OUT, outs):
                tex.bind_to_image(unit, read=False, write=True)
            prog.run((W + 15) // 16, (H + 7) // 8)   # pixelpass.glsl's work groups
            ctx.memory_barrier()   # its image stores seen by the reads and passes after
        else:
            fbo.use()
            fbo.viewport = (0, 0, W, H)
            self._vao(prog).render(ctx.TRIANGLES, vertices=3)
        check_error(ctx, lambda: f"pass {frag} {sorted(defines)}")
        self._unbind()   # (before releasing a framebuffer of its own; on llvmpipe it also hands the
        #                  queued pass to the render threads now, which a stream of frames gains from)
        for obj in uploaded:
            obj.release()
        return outs[0] if len(outs) == 1 else outs

    def _vao(self, prog):
        """The attribute-less vertex array of a program (made once per program)."""
        if id(prog) not in self._vaos:
            self._vaos[id(prog)] = (prog, self.ctx.vertex_array(prog, []))
        return self._vaos[id(prog)][1]

    def _framebuffer_into(self, tex):
        """A framebuffer drawing into one of this backend's own textures (made once per texture)."""
        if id(tex) not in self._fbos:
            self._fbos[id(tex)] = (tex, self.ctx.framebuffer(color_attachments=[tex]))
        return self._fbos[id(tex)][1]

    def _borrow(self, size: tuple[int, int], components: tuple[int, ...], dtype: str):
        """Scratch textures of one shape with their framebuffer, reused across frames:
        (textures, framebuffer, their key in ``_scratch``)."""
        key = (size, components, dtype)
        free = self._scratch.setdefault(key, [])
        if free:
            entry = free.pop()
        else:
            outs = tuple(self.ctx.texture(size, n, dtype=dtype) for n in components)
            entry = (outs, self.ctx.framebuffer(color_attachments=list(outs)), key)
        for t in entry[0]:
            self._lent[id(t)] = entry
        return entry

    def _recycle(self, textures: list) -> None:
        """Give a frame's scratch textures back (the GL orders their next use after the reads
        queued from them)."""
        for t in textures:
            entry = self._lent.pop(id(t), None)
            if entry is not None and all(id(o) not in self._lent for o in entry[0]):
                self._scratch[entry[2]].append(entry)

    def blur_passes(self, grey, depth, optics, sigma_max: float, size: tuple[int, int], temps: list, stages: list):
        """The depth-of-field passes of ``optics.scheme`` (glsim.effects.dof.blur_scheme) on the
        grey texture (or (H, W) array) with its depth; new textures go to ``temps``, pass names
        to ``stages``. Returns the blurred grey texture."""
        scheme = blur_scheme(optics)
        kernel = "disk" if scheme == "disk" else "gaussian"
        uniforms = shader_uniforms(optics)
        # + 1: a pixel's float32 depth may lie an ulp beyond the corners' float64 range
        radius = int(kernel_radius(sigma_max, kernel)) + 1

        def run(name, inputs, components=(1,)):
            # FP64: sigma and window in double from double uniforms, bit for bit numpy's
            defines = {name: None, "MAX_RADIUS": radius, **({"FP64": None} if self.fp64 else {})}
            out = self.fullscreen_pass("blur.frag", defines, {**inputs, "u_depth": depth}, uniforms, size, components,
                                       scratch=temps)
            stages.append(name.lower())
            return out

        first, *second = BLUR_PASSES[scheme]   # (glsim.backends.gl.plan)
        if not second:
            return run(first, {"u_src": grey})
        if scheme == "expansion":
            moments, rows = run(first, {"u_src": grey}, (4, 4))
            return run(second[0], {"u_image": grey, "u_moments": moments, "u_rows": rows})
        h = run(first, {"u_src": grey})
        return run(second[0], {"u_src": h, "u_image": grey} if scheme == "hybrid" else {"u_src": h})

    @staticmethod
    def read(tex) -> np.ndarray:
        """An R32F texture as a float32 (H, W) array (read straight into it: no second copy)."""
        W, H = tex.size
        out = np.empty((H, W), np.float32)
        tex.read_into(out)
        return out

    def _downsample(self, samples, depth, W: int, H: int, s: int, into=None):
        """Box filter over s×s samples: grey, and the mean depth of covered samples if given.
        ``into``: the (grey, depth) textures to draw into, skipping the pixels subsamples.frag
        finished (their candidate count is LIST_DONE; the lists bound as images); else the
        backend's own (:meth:`_output`)."""
        skip = {} if into is None else {"SKIP_DONE": None}
        grey = self.fullscreen_pass("downsample.frag", {"SS": s, **skip}, {"u_samples": samples}, {}, (W, H),
                                    into=self._output((W, H), "grey") if into is None else into[0])
        if depth is None:
            return grey, None
        return grey, self.fullscreen_pass("downsample.frag", {"SS": s, "COVERED_MEAN": None, **skip},
                                          {"u_samples": depth}, {}, (W, H),
                                          into=self._output((W, H), "depth") if into is None else into[-1])

    def _output(self, size: tuple[int, int], role: str, dtype: str = "f4"):
        """This backend's one-component texture of ``size`` for the pixel passes' ``role``
        ("grey", "depth": the box filter's; "quantized"), made once: a view's passes draw into
        the same objects every frame (so they can be replayed: :mod:`glsim.backends.gl.replay`);
        the GL orders a frame's draw after the reads queued from the last."""
        key = (size, role, dtype)
        tex = self._outputs.get(key)
        if tex is None:
            tex = self._outputs[key] = self.ctx.texture(size, 1, dtype=dtype)
        return tex

    def quantize_pass(self, grey, bit_depth: int) -> np.ndarray:
        """shaders/quantize.frag on an R32F texture or (H, W) array: the image as
        :func:`glsim.io.images.quantize` gives it (uint8, or uint16 for 10–16 bits), read back
        in that type. Needs float64 (``self.fp64``)."""
        out = self._quantized(grey, bit_depth)
        return read_texture(self._pack, out, np.uint8 if bit_depth == 8 else np.uint16).fetch(self._pack)

    def _quantized(self, grey, bit_depth: int):
        """The texture of :meth:`quantize_pass` (R8UI / R16UI, :meth:`_output`'s)."""
        H, W = grey.shape if isinstance(grey, np.ndarray) else grey.size[::-1]
        dtype = "u1" if bit_depth == 8 else "u2"
        return self.fullscreen_pass("quantize.frag", {"FP64": None}, {"u_src": grey},
                                    {"u_top": float((1 << bit_depth) - 1)}, (W, H),
                                    into=self._output((W, H), "quantized", dtype), dtype=dtype)

    def noise_pass(self, grey, params, bit_depth: int, seed: int, table=None, scratch: list | None = None):
        """noise.frag on an R32F texture or (H, W) array: grey + σ(grey)·z, the same field as
        :func:`glsim.effects.noise.add_noise` (``scratch``: as for :meth:`fullscreen_pass`)."""
        inputs = {"u_src": grey}
        if params.model == "heteroscedastic":
            inputs["u_variance"] = noise.variance_texture(table, bit_depth)
        H, W = grey.shape if isinstance(grey, np.ndarray) else grey.size[::-1]
        uniforms = {**noise.shader_uniforms(params, bit_depth), "u_seed": int(seed), "u_width": W}
        return self.fullscreen_pass("noise.frag", noise.shader_defines(params), inputs, uniforms, (W, H),
                                    scratch=scratch)

    def camera_passes(self, grey, fx, size: tuple[int, int], scratch: list, stages: list):
        """Vignetting, lens PSF and fixed-pattern noise where ``fx`` asks for them
        (:func:`glsim.backends.gl.sensor_passes.camera_passes`)."""
        return camera_passes(self, grey, fx, size, scratch, stages)
