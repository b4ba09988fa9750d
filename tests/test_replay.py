"""Deformation passes recorded once and replayed (glsim.backends.gl.replay): the same images and
truth, bit for bit, as the passes made by the Python that decides them, whatever ran in between;
a record naming a released object is made again; what a recording keeps and abandons."""
import dataclasses

import pytest

from glsim.render import Renderer
from glsim.scene import Lighting
from _plates import plate_scene
from test_pipeline import _same

# kinds that share programs whose uniforms differ (candidates.comp's u_half at 1 and 4 spp),
# with truth and without, quantised on the GPU (inside the record) or not, Newton's sub-samples
# (a full-screen pass inside); the test runs them lit and unlit
KINDS = [{"mode": "exact", "samples_per_pixel": 1, "truth": True}, {"mode": "exact", "samples_per_pixel": 4},
         {"mode": "q4", "samples_per_pixel": 4, "truth": True, "quantize": True},
         {"mode": "fast", "samples_per_pixel": 1, "quantize": True},
         {"mode": "exact", "samples_per_pixel": 4, "subsamples": "newton", "quantize": True}]


def _made(r: Renderer) -> Renderer:
    """``r`` with replays turned off: every pass made by its Python."""
    r.backend.frames.run = lambda key, refs, make, view=None: make()
    return r


def _jobs(cameras=("c", "d")):
    return [{"camera": c, "step": step, **kind} for _ in range(3) for kind in KINDS for c in cameras
            for step in (0, 1)]


@pytest.mark.gl
@pytest.mark.parametrize("lit", [False, True])
def test_replayed_passes_give_the_bytes_of_made_ones(gl_ctx, lit):
    scene = plate_scene((96, 72), fx=1200.0, second={"name": "d", "t": (-4.0, 0.0, 0.0)},
                        lighting=Lighting() if lit else None)
    # (the two renderers share the context's programs: their uniform writes interleave)
    with Renderer(scene, "gl", ctx=gl_ctx) as r, _made(Renderer(scene, "gl", ctx=gl_ctx)) as ref:
        for a, b in zip(r.render_many(_jobs()), ref.render_many(_jobs())):
            _same(a, b)
        frames = r.backend.frames
        # each key (kind and camera; and q4's s = 1 truth pass) drawn 6 times: made (step 0),
        # recorded (step 1), then replayed for both steps
        keys = (len(KINDS) + 1) * 2
        assert (frames.recordings, frames.replays) == (keys, 4 * keys)


@pytest.mark.gl
def test_a_record_naming_a_released_object_is_made_again(gl_ctx):
    """Cameras of two sizes: each view's candidate lists are released when the other size is
    drawn (one size kept), so a record of one is not live after the other's render."""
    scene = plate_scene((96, 72), fx=1200.0, second={"name": "d", "size": (80, 64), "t": (-4.0, 0.0, 0.0)})
    jobs = [{"camera": c, "mode": "exact"} for c in ("c", "c", "c", "d", "c", "c", "c")]
    with Renderer(scene, "gl", ctx=gl_ctx) as r, _made(Renderer(scene, "gl", ctx=gl_ctx)) as ref:
        out = [r.render(**j) for j in jobs]
        for a, b in zip(out, (ref.render(**j) for j in jobs)):
            _same(a, b)
        frames = r.backend.frames
        # c: made, recorded, replayed; d; c: the record is dead and its lists made again (a
        # recording that makes an object is abandoned); c: recorded again; c: replayed
        assert (frames.recordings, frames.replays) == (2, 2)


@pytest.mark.gl
def test_a_recording_keeps_state_calls_and_abandons_one_that_makes_or_reads(gl_ctx):
    from glsim.backends.gl.context import check_error
    from glsim.backends.gl.replay import recording

    buf = gl_ctx.buffer(bytes(16))
    fbo = gl_ctx.simple_framebuffer((4, 4))
    with recording() as rec:
        buf.bind_to_storage_buffer(5)
        fbo.viewport = (0, 0, 2, 2)           # a property setter
        check_error(gl_ctx, "test")           # glsim's own call: kept as one call
        _ = fbo.size                          # a getter: nothing to repeat
    assert rec.ok and len(rec.ops) == 3 and set(rec.objects.values()) == {buf, fbo}
    fbo.viewport = (0, 0, 4, 4)
    for op in rec.ops:
        op()
    assert fbo.viewport == (0, 0, 2, 2)
    for makes_or_reads in (lambda: gl_ctx.buffer(bytes(4)).release(), lambda: buf.read(), lambda: gl_ctx.error):
        with recording() as rec:
            buf.bind_to_storage_buffer(5)
            makes_or_reads()
        assert not rec.ok and not rec.busy
    with recording() as outer:           # one recording at a time: the other is busy, not abandoned
        with recording() as other:
            buf.bind_to_storage_buffer(5)
    assert outer.ok and len(outer.ops) == 1 and other.busy and not other.ok
    # a view-dependent call: one call in what every view replays, its GL calls in the recorded
    # view's; one that makes an object leaves the recorded view's unusable, not the recording
    from glsim.backends.gl.replay import replayed

    @replayed(view=True)
    def bind_view(make: bool):
        (gl_ctx.buffer(bytes(4)) if make else buf).bind_to_storage_buffer(6)
        buf.bind_to_storage_buffer(7)

    for make in (False, True):
        with recording() as rec:
            fbo.viewport = (0, 0, 2, 2)
            bind_view(make)
        assert rec.ok and len(rec.ops) == 2 and rec.ops[1].func.__name__ == "bind_view"
        assert rec.inline is None if make else (len(rec.inline) == 3 and set(rec.inline_objects.values()) == {buf, fbo})
        assert set(rec.objects.values()) == {fbo}
    buf.release()
    fbo.release()


@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
def test_a_replay_issues_the_made_pass_calls_where_patches_see_them(gl_ctx, stage):
    """A replay looks its methods up when it runs: a patch of moderngl's classes (as driver_time
    and pass_times make) sees the same state-changing calls, in number and kind, as in the
    render that recorded them, and pass timing names the replayed passes (either pixel stage)."""
    import collections
    import functools

    from glsim.backends.gl.timing import patched

    def counting(seen):
        def wrap(fn, cls, name, kind):
            @functools.wraps(fn)
            def inner(*a, **k):
                if kind != "get" and name != "get":     # (reads: a replay has no need of them)
                    seen[cls.__name__, name] += 1
                return fn(*a, **k)
            return inner
        return wrap

    scene = plate_scene((96, 72), fx=1200.0, second={"name": "d", "t": (-4.0, 0.0, 0.0)})
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        r.backend.stage = stage
        kind = {"mode": "exact", "samples_per_pixel": 4, "quantize": True}
        r.render("c", 0, **kind)
        seen = [collections.Counter(), collections.Counter()]
        for counter in seen:                    # recorded, then replayed
            with patched(counting(counter)):
                r.render("c", 0, **kind)
        with r.backend.pass_times() as p:
            r.render("c", 0, **kind)
        assert r.backend.frames.replays == 2 and r.backend.frames.recordings == 1
    assert seen[0] == seen[1] and sum(seen[1].values()) > 50
    ext = {"fragment": "frag", "compute": "comp"}[stage]
    assert {"view.comp", "candidates.comp", f"classify.{ext}", f"deform.{ext}", f"downsample.{ext}",
            f"quantize.{ext}"} <= set(p)


@pytest.mark.gl
def test_a_renderer_given_new_lights_replays_none_of_the_old(gl_ctx):
    """The lights' values are part of a record's key: the same view under other lights is made."""
    scene = plate_scene((96, 72), fx=1200.0, lighting=Lighting())
    brighter = dataclasses.replace(scene, lighting=dataclasses.replace(scene.lighting, ambient=0.5))
    with Renderer(scene, "gl", ctx=gl_ctx) as r, _made(Renderer(brighter, "gl", ctx=gl_ctx)) as ref:
        for _ in range(3):
            r.render("c", 0)
        r.scene = brighter
        _same(r.render("c", 0), ref.render("c", 0))


@pytest.mark.gl
def test_a_library_variant_with_equal_cameras_and_options_replays_them(gl_ctx):
    """A library worker gives its renderer each variant's scene, resolved anew (equal cameras and
    options, new objects): the renderer meets them as the objects it met first, so the views
    carry over and their passes replay; the images are those of each variant made alone."""
    import copy

    from glsim.scene import Noise

    base = dataclasses.replace(plate_scene((96, 72), fx=1200.0, second={"name": "d", "t": (-4.0, 0.0, 0.0)}),
                               noise=Noise(sigma=1.0))
    jobs = [{"camera": c, "step": s, "truth": True, "quantize": True} for c in ("c", "d") for s in (0, 1)]
    with Renderer(base, "gl", ctx=gl_ctx) as r:
        for k in range(4):
            variant = copy.deepcopy(dataclasses.replace(base, noise=Noise(sigma=1.0 + k)))
            r.scene = variant
            with _made(Renderer(variant, "gl", ctx=gl_ctx)) as alone:
                for a, b in zip(r.render_many(jobs), alone.render_many(jobs)):
                    _same(a, b)
        # per camera: variant 0's step 0 made, its step 1 recorded; every other render replayed
        assert (r.backend.frames.recordings, r.backend.frames.replays) == (2, 3 * len(jobs))


def test_objects_equal_but_for_a_zero_sign_are_not_taken_for_each_other():
    """0.0 == −0.0, but a sign can reach a result's bits: only objects with the same repr are one."""
    import copy

    scene = plate_scene((96, 72), fx=1200.0, t=(0.0, 0.0, 0.0))
    signed = dataclasses.replace(scene.cameras[0], t=(-0.0, 0.0, 0.0))
    with Renderer(scene, "cpu") as r:
        assert r._first_equal(signed) is signed and r._first_equal(scene.cameras[0]) is scene.cameras[0]
        assert r._first_equal(copy.deepcopy(scene.cameras[0])) is scene.cameras[0]


@pytest.mark.gl
def test_a_time_series_new_steps_replay_the_pass_of_the_first_ones(gl_ctx):
    """A record serves every view of its camera: each load step of a series drawn once (a
    library over time), lit, with an element that collapses at one step (excluded: its bits and
    flag differ from the other steps') — from the third step on the passes are replays, and the
    images, truth and warnings are those of passes made for each step."""
    import warnings

    import numpy as np

    from glsim.scene.mesh import Mesh
    from test_render import custom_mesh_scene, grid_nodes

    nodes, quads = grid_nodes(8, 6, 20.0, 15.0, 300.0)
    steps = [np.zeros_like(nodes)]
    for k in range(1, 6):
        u = np.zeros_like(nodes)
        u[:, 0], u[:, 1] = 0.3 * k, -0.1 * k * nodes[:, 0] / 10.0
        if k == 3:   # element 0 collapses onto its first node (zero area: excluded)
            u[quads[0]] = u[quads[0, 0]] + nodes[quads[0, 0]] - nodes[quads[0]]
        steps.append(u)
    scene, _ = custom_mesh_scene(nodes, quads, size=(96, 72), fx=1200.0)
    scene = dataclasses.replace(scene, lighting=Lighting())
    mesh = Mesh(nodes=nodes, quads=quads, node_labels=np.arange(1, len(nodes) + 1),
                element_labels=np.arange(101, 101 + len(quads)), displacements=tuple(steps))
    kinds = [{"mode": "exact", "truth": True}, {"mode": "q4", "samples_per_pixel": 4, "quantize": True},
             {"mode": "fast", "quantize": True}]
    jobs = [{"camera": "c", "step": k, **kind} for k in range(6) for kind in kinds]

    def run(r):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            out = list(r.render_many(jobs))
        return out, sorted(str(w.message) for w in seen)

    with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as r, _made(Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh)) as ref:
        (got, warned), (want, warned_ref) = run(r), run(ref)
        assert (r.backend.frames.recordings, r.backend.frames.replays) == (len(kinds), 4 * len(kinds))
    for a, b in zip(got, want):
        _same(a, b)
    assert warned == warned_ref and any("zero area" in w for w in warned)


@pytest.mark.gl
def test_the_recorded_step_drawn_after_its_eviction_replays_through_the_view_calls(gl_ctx):
    """The recorded view's own list names its step's buffers; once later steps have evicted
    them (STEPS_KEPT), that step drawn again replays the camera's record through its
    view-dependent calls (its geometry made and uploaded again), with the bytes of a made pass."""
    from moderngl import InvalidObject

    from glsim.stages.geometry import STEPS_KEPT

    later = range(2, 2 * STEPS_KEPT + 3)   # enough steps to evict step 1's buffers
    scene = plate_scene((96, 72), fx=1200.0, plate=dataclasses.replace(
        plate_scene().specimen.plate, translations=tuple((0.2 * k, 0.0, 0.0) for k in range(1, later[-1] + 1))))
    jobs = [("c", 1), ("c", 1)] + [("c", k) for k in later]
    with Renderer(scene, "gl", ctx=gl_ctx) as r, _made(Renderer(scene, "gl", ctx=gl_ctx)) as ref:
        for a, b in zip(r.render_many(jobs), ref.render_many(jobs)):
            _same(a, b)
        (record,) = r.backend.frames._kept.values()
        assert record.inline is not None and any(type(o.mglo) is InvalidObject for o in record.inline_objects)
        _same(r.render("c", 1), ref.render("c", 1))
        assert r.backend.frames.replays == len(later) + 1


@pytest.mark.gl
def test_a_curved_time_series_replays_each_cameras_record(gl_ctx):
    """Quadratic (Q8) elements in exact and q4: the patches' control points at each step and
    their sagitta per view are bound and written through the view-dependent calls, so the steps
    of a series drawn once by two cameras replay each camera's record from the third step on,
    with the images and truth of passes made for each step (the truth mapped to the patches)."""
    from glsim.evaluation.quadratic import W0, ZC, mesh as q8_mesh
    from glsim.scene import Plate, Scene, Specimen
    from glsim.scene.camera import Camera
    from glsim.scene.mesh import Mesh

    base = q8_mesh("quad8", 4, 3)
    u = base.displacements[1]
    mesh = Mesh(base.nodes, base.quads, base.node_labels, base.element_labels,
                tuple(k / 4 * u for k in range(5)), patches=base.patches)
    W, H = 96, 72
    f = 0.8 * W * ZC / W0
    cam = Camera(name="c", size=(W, H), fx=f, fy=f, cx=(W - 1) / 2 + 0.3, cy=(H - 1) / 2 - 0.4)
    scene = Scene(cameras=(cam, dataclasses.replace(cam, name="d", t=(-1.5, 0.5, 0.0))),
                  specimen=Specimen(plate=Plate(width=1, height=1, nx=1, ny=1)))
    kinds = [{"mode": "exact", "truth": True}, {"mode": "q4", "samples_per_pixel": 4, "truth": True, "quantize": True}]
    jobs = [{"camera": c, "step": k, **kind} for k in range(5) for kind in kinds for c in ("c", "d")]
    with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as r, _made(Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh)) as ref:
        for a, b in zip(r.render_many(jobs), ref.render_many(jobs)):
            _same(a, b)
        keys = 2 * (len(kinds) + 1)   # (per camera; q4's truth is a pass at 1 spp of its own)
        assert (r.backend.frames.recordings, r.backend.frames.replays) == (keys, 3 * keys)

