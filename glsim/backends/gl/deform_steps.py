"""The deformation passes as executor steps: each function issues one pass of a plan
(:class:`glsim.backends.gl.plan.Pass`, named by its ``step``) for the frame being rendered
(:class:`FrameState`), in the order the plan lists them (GLBackend executes them).

Pass 1 (exact, q4): view.comp's element records and covers, the candidate lists
(candidates.comp, then candidates.frag for covers too large for it). Pass 2 at s×s samples per
pixel into the deformation target: in mode fast the element triangles with a depth test (compute
stage: their indices, then fast_shade.comp shading each sample); in exact and q4 the full-screen
programs on classify.frag's depth layers (compute stage: over classify.comp's pixel lists,
dispatched indirectly) and the overflow fallback's cover rectangles. With Newton sub-samples,
subsamples.frag at W×H first finishes the single-candidate pixels.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from glsim.backends.gl.bindings import image, sampler, storage
from glsim.backends.gl.geometry import DRAW_FALLBACK, DRAW_RESOLVE, LAYER_DISPATCH, LAYERS
from glsim.backends.gl.rays import ray_map
from glsim.backends.gl.uniforms import Uniforms, set_uniform

_REF_UNIT, _RAYS_UNIT = sampler("u_ref"), sampler("u_rays")


@dataclass
class FrameState:
    """One request being executed: what it renders (``view``, ``opts``, plan ``plan`` at ``s``
    samples per pixel, ``truth`` maps, effects ``fx``, curved ``patches``, ``quantize`` bits),
    the mesh's buffers ``geo`` and the view's ``uniforms``; filled in by the steps: the frame's
    named textures (``textures``: "samples", "sample_depth", "grey", "depth", …), the
    deformation target's ``color`` textures, Newton's W×H ``pixels``, the ray maps, and ``bind``
    / ``setup`` (what pass 2's programs read)."""
    view: object
    opts: object
    plan: object
    s: int
    truth: bool
    fx: object
    patches: object
    geo: object
    uniforms: Uniforms
    quantize: int | None = None
    blur: tuple | None = None
    textures: dict = field(default_factory=dict)
    color: tuple = ()
    pixels: tuple | None = None
    rays: object = None
    centre_rays: object = None
    bind: Callable[[], None] | None = None
    setup: Callable[[object], None] | None = None

    @property
    def size(self) -> tuple[int, int]:
        return self.view.camera.size

    @property
    def defines(self):
        return self.plan.define_dict


def target(b, width: int, height: int, truth: bool, lo: bool, depth_out: bool):
    """The deformation pass's framebuffer at ``width``×``height``: grey, truth maps (if asked),
    the low halves of (ξ, η) (if ``lo``), depth Z (if asked); with the grey target alone (to
    clear it to the background grey; the others clear to 0) and the depth buffer alone (for
    classify.frag's layers): (framebuffer, colors, depth, grey only, depth only)."""
    def make():
        ctx, size = b.ctx, (width, height)
        color = [ctx.texture(size, 1, dtype="f4")]
        if truth:
            color += [ctx.texture(size, 4, dtype="f4"), ctx.texture(size, 4, dtype="f4")]
        if lo:
            color.append(ctx.texture(size, 2, dtype="f4"))
        if depth_out:
            color.append(ctx.texture(size, 1, dtype="f4"))
        depth = ctx.depth_renderbuffer(size)
        return (ctx.framebuffer(color_attachments=color, depth_attachment=depth), tuple(color), depth,
                ctx.framebuffer(color_attachments=color[:1]), ctx.framebuffer(depth_attachment=depth))
    return b.resources.get(("target", width, height, truth, lo, depth_out), make)


def bindings(b, st: FrameState, lit) -> None:
    """Set ``st.bind()`` (the storage buffers of pass 2, bound once before it: pass 1 may bind
    the float64 nodes at the same points) and ``st.setup(prog)`` (the textures and uniforms of
    pass 2's programs). Every uniform is written on every use: programs are
    shared per context, so a value left by another renderer must not carry over. ``lit``:
    (flat normals, the lights' uniforms) or None."""
    view, p, geo, patches = st.view, st.plan, st.geo, st.patches
    fp64 = "FP64" in st.defines
    dropped = b.dropped_counter()
    lighting = Uniforms(lit[1]) if lit is not None else None
    ref_storage = None
    if p.ref is not None:
        local = p.ref == "REF_LOCAL"
        ref_storage = (geo.ref_local_buffer if local else geo.ref_pinhole_buffer)(view.ref_camera.intrinsic_values)
    speckle = b.speckle_binder(st.opts.interpolation)

    def bind():
        geo.bind_mesh(fp64)
        geo.bind_step(view, fp64)
        if ref_storage is not None:
            ref_storage.bind_to_storage_buffer(storage(p.ref))
        dropped.bind_to_storage_buffer(storage("DROPPED"))
        if patches is not None:
            for name, buf in zip(("PATCH_NODES", "PATCH_REF"), b.patch_buffers(patches, st.opts.mode, fp64)):
                buf.bind_to_storage_buffer(storage(name))
        if lighting is not None:
            geo.normals(view, lit[0]).bind_to_storage_buffer(storage("NORMALS"))

    def setup(prog):
        st.uniforms.write(prog)
        if lighting is not None:
            lighting.write(prog)
        speckle(prog)
        if st.rays is not None:
            st.rays.use(_RAYS_UNIT)

    st.bind, st.setup = bind, setup


def list_program(b, st: FrameState, frag: str, target_fbo, layer: float, textures=None, uniforms=None,
                 indirect: int | None = None) -> None:
    """One full-screen program of pass 2 (lists.vert at window depth ``layer``; the entry file
    ``frag`` tests depth early) into ``target_fbo``; ``indirect``: drawn by that command of pass 1's draws (only where
    pass 1 found work for it)."""
    W, H = st.size
    prog = b.programs.entry(frag, st.defines)
    st.setup(prog)
    st.geo.bind_lists(W, H, textures=True)
    for name, tex in (textures or {}).items():
        tex.use(sampler(name))
    for name, value in {**(uniforms or {}), "u_layer": layer}.items():
        set_uniform(prog, name, value)
    target_fbo.use()
    vao = b.resources.vertex_array(prog)
    if indirect is None:
        vao.render(b.ctx.TRIANGLES, vertices=3)
    else:
        vao.render_indirect(st.geo.draws(W, H), b.ctx.TRIANGLES, count=1, first=indirect)


# ---- pass 1 ------------------------------------------------------------------------------------
def rays(b, st, ps) -> None:
    st.rays = ray_map(b.resources, b.programs, st.view.camera, st.s, st.plan.rays, st.fx.aperture)


def view_records(b, st, ps) -> None:
    grow = 0.5 - 0.5 / st.s
    if st.plan.camera_local:
        st.geo.view_pass(st.view, st.uniforms, st.opts.mode, True, grow, local=True)
    else:
        st.geo.view_pass(st.view, st.uniforms, st.opts.mode, "FP64" in st.defines, grow=grow)
    st.geo.view_passes += 1


def candidates(b, st, ps) -> None:
    st.geo.candidates_pass(*st.size, st.s)


def big_covers(b, st, ps) -> None:
    st.geo.big_covers_pass(*st.size, st.s)
    st.bind()


# ---- Newton's sub-samples (pass 2a, W×H) ----------------------------------------------------------
def newton_layers(b, st, ps) -> None:
    """subsamples.frag's W×H target cleared, its pixels' depth set to their candidate count's layer."""
    ctx, (W, H) = b.ctx, st.size
    fbo, color, _, grey, depth = target(b, W, H, False, False, "DEPTH_OUT" in st.defines)
    fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    grey.clear(st.opts.background, 0.0, 0.0, 0.0)
    ctx.enable(ctx.DEPTH_TEST)
    st.geo.classify_pass(depth, W, H, 1)
    ctx.depth_func, fbo.depth_mask = "==", False
    st.pixels = color


def centre_rays(b, st, ps) -> None:
    st.centre_rays = ray_map(b.resources, b.programs, st.view.camera, 1, st.plan.rays)


def newton(b, st, ps) -> None:
    """The single-candidate pixels done from their centre by Newton (subsamples.frag)."""
    ctx, (W, H) = b.ctx, st.size
    fbo = target(b, W, H, False, False, "DEPTH_OUT" in st.defines)[0]
    list_program(b, st, "subsamples.frag", fbo, LAYERS["single.frag"], {"u_centre_rays": st.centre_rays},
                 {"u_background": float(st.opts.background)})
    ctx.depth_func, fbo.depth_mask = "<", True
    ctx.memory_barrier()   # its LIST_DONE marks seen by the passes below


# ---- pass 2 at s×s samples per pixel ------------------------------------------------------------
def _sample_target(b, st):
    """The deformation target at s×s samples per pixel, cleared (grey to the background, truth
    and depth to zero) and drawn into; the frame's textures named after it."""
    ctx, (W, H), s, d = b.ctx, st.size, st.s, st.defines
    fbo, color, _, grey, depth = target(b, W * s, H * s, st.truth, "TRUTH_LO" in d, "DEPTH_OUT" in d)
    fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
    grey.clear(st.opts.background, 0.0, 0.0, 0.0)
    fbo.use()
    fbo.viewport = (0, 0, W * s, H * s)
    ctx.disable(ctx.CULL_FACE)
    st.color = color
    named = {"samples": color[0], **({"sample_depth": color[-1]} if "DEPTH_OUT" in d else {})}
    st.textures.update(named)
    if s == 1:
        st.textures.update(grey=color[0], **({"depth": color[-1]} if "DEPTH_OUT" in d else {}))
    return fbo, color, depth


def _target_images(st) -> tuple[int, ...]:
    """The image units single.comp, resolve.comp and fast_shade.comp write the deformation target's textures through, in the
    order of :func:`target`'s colors."""
    d = st.defines
    names = ["GREY", *(["MAP", "EXTRA"] if st.truth else []), *(["LO"] if "TRUTH_LO" in d else []),
             *(["DEPTH"] if "DEPTH_OUT" in d else [])]
    return tuple(image(n) for n in names)


def fast(b, st, ps) -> None:
    """Mode fast: the element triangles, projected in the vertex stage, with a depth test."""
    st.bind()
    _sample_target(b, st)
    prog = b.programs.entry("fast.frag", st.defines)
    st.setup(prog)
    b.ctx.enable(b.ctx.DEPTH_TEST)
    st.geo.draw(prog)
    b.ctx.disable(b.ctx.DEPTH_TEST)


def fast_ids(b, st, ps) -> None:
    """Mode fast in the compute pixel stage: the element triangles drawn as in the fragment
    stage (the same depth test and discards) into a target of triangle indices,
    fast_records.geom keeping their records (fast_ids.frag)."""
    ctx, (W, H), s = b.ctx, st.size, st.s
    st.bind()
    _sample_target(b, st)
    w, h = W * s, H * s

    def make():
        ids, depth = ctx.texture((w, h), 1, dtype="u4"), ctx.depth_renderbuffer((w, h))
        return ctx.framebuffer(color_attachments=[ids], depth_attachment=depth), ids, depth
    fbo = b.resources.latest("visibility", (w, h), make)[0]
    fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)   # (index 0: no triangle)
    fbo.use()
    fbo.viewport = (0, 0, w, h)
    st.geo.fast_records().bind_to_storage_buffer(storage("FAST_TRIANGLES"))
    prog = b.programs.entry("fast_ids.frag", st.defines)
    st.setup(prog)
    ctx.enable(ctx.DEPTH_TEST)
    st.geo.draw(prog)
    ctx.disable(ctx.DEPTH_TEST)
    ctx.memory_barrier()   # the records and indices seen by the compute pass


def fast_shade(b, st, ps) -> None:
    """fast_shade.comp shading every sample from its triangle's record."""
    w, h = st.size[0] * st.s, st.size[1] * st.s
    ids = b.resources.latest("visibility", (w, h), None)[1]
    comp = b.programs.compute("fast_shade.comp", st.defines)
    st.setup(comp)
    ids.use(sampler("u_visibility"))
    for unit, tex in zip(_target_images(st), st.color):
        tex.bind_to_image(unit, read=False, write=True)
    comp.run((w + 15) // 16, (h + 7) // 8)   # fast_shade.comp's work groups
    b.ctx.memory_barrier()


def pixel_lists(b, st, ps) -> None:
    """classify.comp's lists of the pixels with one candidate and with several, and their
    indirect dispatches; the target's textures bound as images."""
    W, H = st.size
    _sample_target(b, st)
    st.textures["lists"] = st.geo.layer_pass(W, H, st.s)
    st.geo.bind_lists(W, H, textures=True)
    for unit, tex in zip(_target_images(st), st.color):
        tex.bind_to_image(unit, read=False, write=True)


def listed(b, st, ps) -> None:
    """single.comp or resolve.comp over their pixel list, dispatched indirectly."""
    prog = b.programs.compute(ps.shader, st.defines)
    st.setup(prog)
    prog.run_indirect(st.textures["lists"], LAYER_DISPATCH[ps.shader])
    if ps.shader == "resolve.comp":
        b.ctx.memory_barrier()   # the image stores seen by the fallback's draws and the passes after


def layers(b, st, ps) -> None:
    """classify.frag: each sample's depth set to its pixel's candidate count's layer."""
    W, H = st.size
    fbo, _, depth = _sample_target(b, st)
    b.ctx.enable(b.ctx.DEPTH_TEST)
    st.geo.classify_pass(depth, W, H, st.s)
    b.ctx.depth_func, fbo.depth_mask = "==", False


def layer(b, st, ps) -> None:
    """single.frag on the single-candidate layer, or resolve.frag on the several-candidate one
    (drawn only where pass 1 found such pixels)."""
    W, H, s = *st.size, st.s
    fbo = target(b, W * s, H * s, st.truth, "TRUTH_LO" in st.defines, "DEPTH_OUT" in st.defines)[0]
    several = ps.shader == "resolve.frag"
    list_program(b, st, ps.shader, fbo, LAYERS[ps.shader], indirect=DRAW_RESOLVE if several else None)
    if several:
        b.ctx.depth_func, fbo.depth_mask = "<", True


def overflow(b, st, ps) -> None:
    """Pixels with more candidates than the lists hold: the cover rectangles (drawn only where
    pass 1 found such pixels)."""
    ctx, (W, H) = b.ctx, st.size
    prog = b.programs.entry("overflow.frag", st.defines)
    st.setup(prog)
    st.geo.bind_lists(W, H, textures=True)
    ctx.enable(ctx.DEPTH_TEST)
    st.geo.draw(prog, (st.geo.draws(W, H), DRAW_FALLBACK))
    ctx.disable(ctx.DEPTH_TEST)


STEPS = {"rays": rays, "view": view_records, "candidates": candidates, "big_covers": big_covers,
         "newton_layers": newton_layers, "centre_rays": centre_rays, "newton": newton, "fast": fast,
         "fast_ids": fast_ids, "fast_shade": fast_shade, "pixel_lists": pixel_lists, "listed": listed,
         "layers": layers, "layer": layer, "overflow": overflow}
