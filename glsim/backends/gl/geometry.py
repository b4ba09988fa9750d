"""The mesh on the GPU: uploaded once per renderer and once per load step; per view only uniforms,
one compute dispatch (modes exact and q4) and one draw call.

Buffers (std430 bindings, see ``shaders/view.glsl``): 5 connectivity (ivec4 per element),
6 the step's deformed nodes relative to the mesh's origin, 7 reference-image coordinates per
node, 8 undeformed nodes in the reference camera's frame, 10 the warnings' bitsets, 11 the
step's shape filter (``shaders/shape.comp``); per view, written by ``view.comp``: 0 the element
records pass 2 reads (sample_map.glsl), 9 the cover rectangles exact.vert draws. Node data exist in float64
for FP64 programs and float32 for the others, each made when first needed.

The CPU work per view and per load step hardly depends on the element count: uniforms, a
dispatch, a draw with an index buffer made once, and the problem flags (16 bytes of "any
problem" markers and two bits per element) and the step's shape filter (its bounds on the
elements' areas and folds, :func:`shape_candidates`) copied on the GPU, fetched with the image
and cleared; the bitsets are decoded only when a marker is set, and the step's zero-area, tiny
and folded elements classified in numpy (:meth:`glsim.imaging.geometry.StepGeometry.shape`)
only when the filter says some element may be one.
"""
from __future__ import annotations

import functools
from collections import OrderedDict

import numpy as np

from glsim.backends.gl.bindings import image, sampler, storage
from glsim.backends.gl.uniforms import set_uniform
from glsim.imaging.geometry import STEPS_KEPT, MeshGeometry, ViewSpec
from glsim.imaging.view import GRAZING_COS, NEAR_MM, TINY_AREA_REL, ray_radius

_CORNERS = np.array([0, 1, 2, 0, 2, 3], np.uint32)  # two triangles per element, as the oracle's fast mode
_GROUP = 64          # view.comp's and candidates.comp's local size
_MESH_BINDINGS = tuple(storage(n) for n in ("QUADS", "REF_UV", "REF_XR", "FLAGS"))   # (bind_mesh)
_NODES, _SHAPE = storage("NODES"), storage("SHAPE")
SHAPE_BIAS, SHAPE_BINS = 150, 280   # shaders/shape.comp's histogram of area bounds' exponents
SHAPE_BYTES = 4 * (4 + SHAPE_BINS)
CANDIDATES = 8       # candidates.glsl: elements listed per pixel before it overflows
# classify.frag's window depths: the full-screen pass 2 program run on each (lists.vert)
LAYERS = {"single.frag": 0.25, "resolve.frag": 0.5}
# the compute stage's layers: their dispatch commands' byte offsets in the lists' buffer, and
# what the buffer starts as (pixellists.glsl: no groups yet, lengths 0)
LAYER_DISPATCH = {"single.comp": 0, "resolve.comp": 12}
_LAYERS_START = np.array([0, 1, 1, 0, 1, 1, 0, 0], np.uint32).tobytes()
_MAX_GROUPS = 65535  # per dispatch dimension
_CAND_COUNT, _CAND_LIST, _TIGHT = image("CAND_COUNT"), image("CAND_LIST"), storage("TIGHT")
_COUNT_UNIT, _LIST_UNIT = sampler("u_count_tex"), sampler("u_list_tex")


def _bitset_words(M: int) -> int:
    return max(1, (M + 31) // 32)


def unpack_bits(words: bytes, M: int) -> np.ndarray:
    return np.unpackbits(np.frombuffer(words, np.uint8), bitorder="little")[:M].astype(bool)


def shape_candidates(words: np.ndarray, M: int) -> bool:
    """Whether some element of a step may be zero-area, tiny or folded as
    :func:`glsim.imaging.view.classify_shapes` finds them, from shaders/shape.comp's ``words``
    (uint32) for its ``M`` elements: some n1·n2 may be negative, or the least lower bound on an
    area is at most TINY_AREA_REL × U, U bounding numpy's median area from above — numpy's
    median of M positive areas is at most its (M // 2 + 1)-th smallest, hence at most the
    same order statistic of the upper bounds, which lies below the power of two U that ends
    its histogram bin. Otherwise every area exceeds TINY_AREA_REL × the median (so all are
    positive and none is zero or tiny) and no n1·n2 is negative: no element is excluded."""
    if M == 0:
        return False
    hist = words[4:4 + SHAPE_BINS]
    if words[0] or int(hist.sum()) != M:
        return True
    b = int(hist.cumsum().searchsorted(M // 2 + 1))
    U = np.inf if b >= SHAPE_BINS - 1 else 2.0 ** (b - SHAPE_BIAS)
    low = float((~words[1:2]).view(np.float32)[0])
    return not low > TINY_AREA_REL * U * (1 + 1e-9)   # (the product's rounding: 1e-9 ≫ 2^-53)


_NOTHING_MARKED = bytes(16)   # the status header when no element was marked
DRAW_BIG, DRAW_FALLBACK, DRAW_RESOLVE = 0, 1, 2   # the list flags' indirect draw commands (candidates.glsl)


def _release(value) -> None:
    """Release the GL object ``value``, or those in the tuple ``value`` (other items ignored)."""
    for obj in (value if isinstance(value, tuple) else (value,)):
        if hasattr(obj, "release"):
            obj.release()


class GeometryBuffers:
    """The GL buffers of one :class:`~glsim.imaging.geometry.MeshGeometry` on one context."""

    def __init__(self, ctx, programs, geo: MeshGeometry):
        self.ctx = ctx
        self.programs = programs
        self.geo = geo
        self.M = len(geo.quads)
        self.words = _bitset_words(self.M)   # uint32 words of one problem bitset
        self._bufs: dict = {}
        self._mesh: dict = {}       # fp64 → what _mesh_buffers returns (its buffers are in _bufs)
        self._vaos: dict = {}       # (program, indexed) → its attribute-less vertex array
        self._steps: OrderedDict = OrderedDict()     # (step, fp64) → (StepGeometry, (nodes, shape)) (_per_step)
        self._normals: OrderedDict = OrderedDict()   # (step, flat) → (StepGeometry, buffer) (_per_step)
        self.uploads = {"mesh": 0, "step": 0}   # what was uploaded (tests)
        self.view_passes = 0

    # ---- uploads ---------------------------------------------------------------------------
    def _buffer(self, key, make):
        if key not in self._bufs:
            self._bufs[key] = make()
        return self._bufs[key]

    def _mesh_buffers(self, fp64: bool):
        """(quads, ref_uv, ref_xr, flags): the mesh's buffers in float64 or float32, made once."""
        hit = self._mesh.get(fp64)
        if hit is None:
            hit = self._mesh[fp64] = self._make_mesh_buffers(fp64)
        return hit

    def _make_mesh_buffers(self, fp64: bool):
        geo, ctx = self.geo, self.ctx
        dt = np.float64 if fp64 else np.float32
        quads = self._buffer("quads", lambda: ctx.buffer(np.ascontiguousarray(geo.quads, np.int32).tobytes()))
        if ("ref_uv", fp64) not in self._bufs:
            Xr, ref_uv = geo.reference()   # raises here if the reference camera cannot see the mesh
            self._bufs["ref_uv", fp64] = ctx.buffer(np.ascontiguousarray(ref_uv, dt).tobytes())
            self._bufs["ref_xr", fp64] = ctx.buffer(np.ascontiguousarray(Xr, dt).tobytes())
            self.uploads["mesh"] += 1
        flags = self._buffer("flags", lambda: ctx.buffer(bytes(16 + 8 * self.words)))
        return quads, self._bufs["ref_uv", fp64], self._bufs["ref_xr", fp64], flags

    def _reference_corners(self) -> np.ndarray:
        """Each element's undeformed corners in the reference camera's frame, (M, 4, 3) float64, mm."""
        Xr, _ = self.geo.reference()
        return np.asarray(Xr, np.float64).reshape(-1, 3)[np.asarray(self.geo.quads)]

    def ref_local_buffer(self, intrinsics: tuple):
        """Per element, 20 float32 (binding REF_LOCAL, sample_map.glsl): its undeformed corners in
        the reference camera's frame relative to their centre X̄ (4 × 3, mm), X̄ (3), 0, and the
        reference pixel of X̄ as float32 hi (2) + lo (2) — all from float64, so that a float32
        shader projects X̄ + Δ as ū + J Δ-exact differences, not 600 mm positions (made once)."""
        key = ("ref_local", tuple(intrinsics))
        if key not in self._bufs:
            R = self._reference_corners()
            c = R.mean(axis=1)
            fx, fy, skew, cx, cy = np.asarray(intrinsics, np.float64)
            with np.errstate(divide="ignore", invalid="ignore"):
                x, y = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
            uv = np.stack([fx * x + skew * y + cx, fy * y + cy], 1)
            uv = np.where(np.isfinite(uv), uv, 0.0)
            hi = uv.astype(np.float32)
            rec = np.concatenate([(R - c[:, None]).reshape(-1, 12), c, np.zeros((len(c), 1)), hi,
                                  uv - hi.astype(np.float64)], 1).astype(np.float32)
            self._bufs[key] = self.ctx.buffer(np.ascontiguousarray(rec).tobytes())
        return self._bufs[key]

    def ref_pinhole_buffer(self, intrinsics: tuple):
        """Per element, 12 float64 (binding REF_PINHOLE, sample_map.glsl): its undeformed corners
        in a pinhole reference camera's frame as (fx X + skew Y + cx Z, fy Y + cy Z, Z) (px·mm,
        px·mm, mm), so that the reference pixel of a point is their bilinear blend divided by
        its third component (made once)."""
        key = ("ref_pinhole", tuple(intrinsics))
        if key not in self._bufs:
            R = self._reference_corners()
            fx, fy, skew, cx, cy = np.asarray(intrinsics, np.float64)
            X, Y, Z = R[..., 0], R[..., 1], R[..., 2]
            rec = np.stack([fx * X + skew * Y + cx * Z, fy * Y + cy * Z, Z], -1)
            self._bufs[key] = self.ctx.buffer(np.ascontiguousarray(rec, np.float64).tobytes())
        return self._bufs[key]

    def fast_records(self):
        """Mode fast's triangle records in the compute pixel stage: FAST_RECORD (24) floats for
        each of the 2 M triangles (shaders/fasttriangles.glsl; fast.geom writes them every draw)."""
        return self._buffer("fast_records", lambda: self.ctx.buffer(reserve=max(1, 2 * self.M * 24 * 4)))

    def index_buffer(self):
        """Six indices per element into the 4 M attribute-less vertices (made once)."""
        def make():
            idx = (np.arange(self.M, dtype=np.uint32)[:, None] * 4 + _CORNERS[None]).ravel()
            return self.ctx.buffer(idx.tobytes())
        return self._buffer("index", make)

    def _per_step(self, cache: OrderedDict, key, step_geo, make):
        """``cache[key]`` made for ``step_geo`` (by ``make()``: an upload) unless it was made for
        it already; the last 2·STEPS_KEPT kept, the GL buffers of those dropped released."""
        hit = cache.get(key)
        if hit is not None and hit[0] is step_geo:
            cache.move_to_end(key)
            return hit[1]
        if hit is not None:
            _release(cache.pop(key)[1])
        value = make()
        cache[key] = (step_geo, value)
        self.uploads["step"] += 1
        while len(cache) > 2 * STEPS_KEPT:
            _release(cache.popitem(last=False)[1][1])
        return value

    def _step_buffers(self, view: ViewSpec, fp64: bool):
        """The step's nodes (float64 or float32) and its shape filter (SHAPE_BYTES, written by
        shaders/shape.comp from those nodes when they are uploaded)."""
        def make():
            nodes = self.ctx.buffer(np.ascontiguousarray(view.step_geo.local, np.float64 if fp64 else np.float32))
            shape = self.ctx.buffer(bytes(SHAPE_BYTES))
            prog = self.programs.compute("shape.comp", {"FP64": None} if fp64 else {})
            self._mesh_buffers(fp64)[0].bind_to_storage_buffer(storage("QUADS"))
            nodes.bind_to_storage_buffer(_NODES)
            shape.bind_to_storage_buffer(_SHAPE)
            set_uniform(prog, "u_count", self.M)
            self._per_element(prog)
            return nodes, shape
        return self._per_step(self._steps, (view.step_geo.index, fp64), view.step_geo, make)

    def shape_buffer(self, view: ViewSpec, fp64: bool | None = None):
        """The shape filter of the view's step, from its float64 or float32 nodes (``fp64``;
        None: one already made from either, else from float64)."""
        if fp64 is not None:
            return self._step_buffers(view, fp64)[1]
        for fp64 in (True, False):
            hit = self._steps.get((view.step_geo.index, fp64))
            if hit is not None and hit[0] is view.step_geo:
                return hit[1][1]
        return self._step_buffers(view, True)[1]

    def normals(self, view: ViewSpec, flat: bool):
        """The step's unit corner normals in the world frame (the lighting's: per element for
        ``flat``, else per node, area-weighted; float32, 12 per element), computed and uploaded
        once per step (binding NORMALS when lit; kept as the step's nodes are); shading.glsl
        rotates them into the camera's frame."""
        def make():
            from glsim.effects import lighting as shade

            nodes, quads = view.step_geo.deformed, self.geo.quads
            if flat:
                n = np.repeat(shade.element_normals(nodes, quads)[:, None], 4, axis=1)
            else:
                n = shade.vertex_normals(nodes, quads)[quads]
            return self.ctx.buffer(np.ascontiguousarray(n, np.float32).tobytes())
        return self._per_step(self._normals, (view.step_geo.index, flat), view.step_geo, make)

    def bind_mesh(self, fp64: bool) -> None:
        """Bind the mesh's buffers (uploaded once per renderer)."""
        for point, buf in zip(_MESH_BINDINGS, self._mesh_buffers(fp64)):
            buf.bind_to_storage_buffer(point)

    def bind_step(self, view: ViewSpec, fp64: bool) -> None:
        """Bind the view's step's nodes (uploaded once per step)."""
        self._step_buffers(view, fp64)[0].bind_to_storage_buffer(_NODES)

    def camera_values(self, camera) -> dict:
        """view.glsl's constants for this mesh seen by ``camera`` (uniform name → value)."""
        r = ray_radius(camera)
        return {"u_near": NEAR_MM, "u_grazing_cos": GRAZING_COS, "u_ray_r": r if np.isfinite(r) else -1.0,
                "u_flag_words": self.words, "u_count": self.M}

    # ---- the per-view pass -----------------------------------------------------------------
    def view_pass(self, view: ViewSpec, uniforms, mode: str, fp64: bool, grow: float = 0.0,
                  local: bool = False) -> None:
        """view.comp on ``view`` (its camera's and its own ``uniforms``): element records
        (binding ELEMENTS), cover rectangles (COVER, grown by ``grow`` px for pass 1 at pixel
        resolution) and tight rectangles (TIGHT); with ``local`` (exact, float64) also the float32
        records of sample_map.glsl's CAMERA_LOCAL (LOCAL)."""
        defines = {f"MODE_{mode.upper()}": None, **({"FP64": None} if fp64 else {}),
                   **({"RECORD_LOCAL": None} if local else {})}
        prog = self.programs.compute("view.comp", defines)
        self.bind_mesh(fp64)
        self.bind_step(view, fp64)
        uniforms.write(prog)
        if prog.get("u_cover_grow", None) is not None:
            set_uniform(prog, "u_cover_grow", float(grow))
        size = 8 if fp64 else 4
        elem = self._buffer(("elem", fp64), lambda: self.ctx.buffer(reserve=max(1, self.M * 12 * size)))
        cover = self._buffer("cover", lambda: self.ctx.buffer(reserve=max(1, self.M * 4 * 8)))
        tight = self._buffer("tight", lambda: self.ctx.buffer(reserve=max(1, self.M * 2 * 16)))
        elem.bind_to_storage_buffer(storage("ELEMENTS"))
        if local:
            self._buffer("local", lambda: self.ctx.buffer(reserve=max(1, self.M * 32 * 4))).bind_to_storage_buffer(storage("LOCAL"))
        cover.bind_to_storage_buffer(storage("COVER"))
        tight.bind_to_storage_buffer(storage("TIGHT"))
        self._per_element(prog)
        self.ctx.memory_barrier()

    def _per_element(self, prog) -> None:
        """Dispatch compute ``prog`` with one invocation per element (groups of _GROUP, in 2-D
        beyond _MAX_GROUPS groups)."""
        groups = (self.M + _GROUP - 1) // _GROUP
        gx = min(groups, _MAX_GROUPS)
        prog.run(group_x=gx, group_y=(groups + gx - 1) // gx)

    # ---- candidate lists (modes exact and q4) -----------------------------------------------
    def _sized(self, name: str, W: int, H: int, make):
        """``make()``'s GL object(s) for the image size W×H under ``name``, made once; those made
        for another size are released (a renderer draws one camera size after another)."""
        key = (name, W, H)
        hit = self._bufs.get(key)
        if hit is None:
            for k in [k for k in self._bufs if isinstance(k, tuple) and k[0] == name]:
                _release(self._bufs.pop(k))
            hit = self._bufs[key] = make()
        return hit

    def _lists(self, W: int, H: int):
        """Per-pixel candidate count (r32ui) and list (CANDIDATES layers), a framebuffer to clear
        the counts and an attachment-less one for pass 1, and the list flags (candidates.glsl)."""
        ctx = self.ctx

        def make():
            count = ctx.texture((W, H), 1, dtype="u4")
            lists = ctx.texture_array((W, H, CANDIDATES), 1, dtype="u4")
            return (count, lists, ctx.framebuffer(color_attachments=[count]), ctx.empty_framebuffer((W, H)),
                    ctx.buffer(self._draw_commands))
        return self._sized("lists", W, H, make)

    @functools.cached_property
    def _draw_commands(self) -> bytes:
        """The list flags' indirect draw commands before pass 1 (candidates.glsl): each draw's
        vertex count, its instance count 0 (pass 1 sets it to 1 where the draw is needed).
        moderngl's ``render_indirect`` reads command ``first`` at byte 20·first, indexed or not."""
        n = 6 * self.M
        return np.array([n, 0, 0, 0, 0, n, 0, 0, 0, 0, 3, 0, 0, 0, 0], np.uint32).tobytes()

    def draws(self, W: int, H: int):
        """The indirect draw commands pass 1 completed for a W×H view (see DRAW_*)."""
        return self._lists(W, H)[4]

    def candidates_pass(self, W: int, H: int, s: int) -> None:
        """Pass 1: list, per pixel, the elements whose tight rectangle meets its s×s samples:
        candidates.comp, one invocation per element over its cover's box (the rectangles written
        by :meth:`view_pass`); :meth:`big_covers_pass` then lists the elements whose box was too
        large for it."""
        clear, flags = self._lists(W, H)[2], self._lists(W, H)[4]
        clear.clear(0.0, 0.0, 0.0, 0.0)
        flags.write(self._draw_commands)
        flags.bind_to_storage_buffer(storage("LIST_FLAGS"))
        self.bind_lists(W, H)
        self._bufs["cover"].bind_to_storage_buffer(storage("COVER"))
        prog = self.programs.compute("candidates.comp")
        set_uniform(prog, "u_count", self.M)
        set_uniform(prog, "u_size", (W, H))
        set_uniform(prog, "u_half", 0.5 - 0.5 / s)
        self._per_element(prog)
        self.ctx.memory_barrier()

    def big_covers_pass(self, W: int, H: int, s: int) -> None:
        """Pass 1's second part: the elements candidates.comp left to their cover triangles
        (candidates.frag), drawn only if there are any (an indirect draw pass 1 set)."""
        empty, flags = self._lists(W, H)[3:]
        prog = self.programs.program("exact.vert", "candidates.frag", defines={"BIG_ONLY": None})
        set_uniform(prog, "u_size", (float(W), float(H)))
        set_uniform(prog, "u_half", 0.5 - 0.5 / s)
        empty.use()
        empty.viewport = (0, 0, W, H)
        self.draw(prog, (flags, DRAW_BIG))
        self.ctx.memory_barrier()

    def classify_pass(self, depth_only, W: int, H: int, s: int) -> None:
        """Pass 1b: each sample's depth set to the layer of its pixel's candidate count
        (classify.frag into ``depth_only``, the deformation target's depth buffer at s×s samples
        per pixel, cleared to 1; depth test on)."""
        prog = self.programs.program("lists.vert", "classify.frag", defines={
            "SS": s, "LAYER_SINGLE": LAYERS["single.frag"], "LAYER_MULTIPLE": LAYERS["resolve.frag"]})
        set_uniform(prog, "u_layer", 0.0)
        self.bind_lists(W, H)
        depth_only.use()
        self._vao(prog, indexed=False).render(self.ctx.TRIANGLES, vertices=3)

    def layer_pass(self, W: int, H: int, s: int):
        """Pass 1b of the compute pixel stage: classify.comp lists the pixels with one candidate
        and those with 2..CANDIDATES (shaders/pixellists.glsl) and sets their indirect dispatches
        (one invocation per sample at ``s``×``s`` per pixel);
        returns the lists' buffer (binding PIXEL_LISTS; dispatch offsets LAYER_DISPATCH)."""
        buf = self._sized("pixel_lists", W, H, lambda: self.ctx.buffer(reserve=4 * (8 + W * H)))
        buf.write(_LAYERS_START)
        buf.bind_to_storage_buffer(storage("PIXEL_LISTS"))
        self.bind_lists(W, H)
        self.programs.compute("classify.comp", {"SS": s}).run((W + 15) // 16, (H + 7) // 8)
        self.ctx.memory_barrier()   # the lists and their dispatches seen by the passes after
        return buf

    def bind_lists(self, W: int, H: int, textures: bool = False) -> None:
        """The lists as images (pass 1) and, with ``textures`` (pass 2), as the textures
        u_count_tex and u_list_tex."""
        count, lists = self._lists(W, H)[:2]
        count.bind_to_image(_CAND_COUNT, read=True, write=True)
        lists.bind_to_image(_CAND_LIST, read=True, write=True)
        self._bufs["tight"].bind_to_storage_buffer(_TIGHT)
        if textures:
            count.use(_COUNT_UNIT)
            lists.use(_LIST_UNIT)

    def list_flags(self, W: int, H: int) -> tuple[bool, bool]:
        """Whether some pixel has more than one candidate, and whether one has more than the
        lists hold (then the fallback draws it): the last view's draws, read back (waits for the
        GPU; for tests and diagnostics — rendering never reads them)."""
        words = np.frombuffer(self.draws(W, H).read(), np.uint32).reshape(3, 5)[:, 1]
        return bool(words[DRAW_RESOLVE]), bool(words[DRAW_FALLBACK])

    def draw(self, prog, indirect: tuple | None = None) -> None:
        """All elements' triangles (attribute-less vertices, the index buffer made once);
        ``indirect`` (buffer, command): as many times as that command's instance count."""
        vao = self._vao(prog, indexed=True)
        if indirect is None:
            vao.render(self.ctx.TRIANGLES, vertices=6 * self.M)
        else:
            vao.render_indirect(indirect[0], self.ctx.TRIANGLES, count=1, first=indirect[1])

    def _vao(self, prog, indexed: bool):
        """A program's attribute-less vertex array (with the index buffer if ``indexed``), made once."""
        key = (prog, indexed)
        if key not in self._vaos:
            index = {"index_buffer": self.index_buffer(), "index_element_size": 4} if indexed else {}
            self._vaos[key] = self.ctx.vertex_array(prog, [], **index)
        return self._vaos[key]

    def status(self) -> tuple[object, int]:
        """The problem flags' buffer and its size in bytes: a 16-byte header (whether anything was
        marked grazing / unprojectable) and one bitset per kind."""
        return self._bufs["flags"], 16 + 8 * self.words

    def clear_status(self) -> None:
        """Clear the problem flags for the next view (after :meth:`status` was copied)."""
        flags, size = self.status()
        flags.write(bytes(size))

    def problems(self, view: ViewSpec, status: bytes, shape: bytes) -> dict:
        """This view's element problems: the step's shape problems — classified in numpy only
        where its shape filter (``shape``, the bytes of :meth:`shape_buffer`) says some element
        may have one — and what the GPU marked (grazing, does not project) in ``status`` (the
        bytes of :meth:`status` after its passes), grazing without the zero-area, tiny and
        folded elements, as sorted index arrays; only the problems some element has (read
        only: with nothing marked, the step's own dict)."""
        sg = view.step_geo
        shaped = sg.shape_known or shape_candidates(np.frombuffer(shape, np.uint32), self.M)
        found = sg.problems() if shaped else {}
        if status[:16] == _NOTHING_MARKED:
            return found
        out = dict(found)
        any_, words = np.frombuffer(status[:16], np.uint32), self.words
        for k, name in enumerate(("grazing", "unprojectable")):
            if any_[k]:
                bits = unpack_bits(status[16 + 4 * words * k:16 + 4 * words * (k + 1)], self.M)
                if k == 0 and shaped:
                    bits &= ~sg.shape()["excluded"]
                out[name] = np.flatnonzero(bits)
        return {k: v for k, v in out.items() if len(v)}

    def buffer_bytes(self) -> int:
        """The bytes of the storage buffers held: the mesh's, the kept steps' nodes, shape filters
        and normals (not the candidate lists' textures)."""
        held = [b for b in self._bufs.values() if not isinstance(b, tuple)]
        held += [b for _, (nodes, shape) in self._steps.values() for b in (nodes, shape)]
        held += [b for _, b in self._normals.values()]
        return sum(b.size for b in held)

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        self._vaos.clear()
        for b in self._bufs.values():
            _release(b)
        for _, value in (*self._steps.values(), *self._normals.values()):
            _release(value)
        self._normals.clear()
        self._bufs.clear()
        self._mesh.clear()
        self._steps.clear()
