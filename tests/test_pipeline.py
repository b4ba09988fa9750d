"""Pipelined rendering (``Renderer.render_many``): the same images and truth, bit for bit, as
one render at a time, in every mode and with both backends; a steady stream of frames makes no
new GL objects; a stream stopped early leaves nothing queued."""
import dataclasses

import numpy as np
import pytest

from glsim.errors import SceneError
from glsim.render import Renderer
from glsim.scene import Noise
from _plates import plate_scene, same_result

BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


def _scene(mode: str, spp: int):
    scene = plate_scene((96, 72), fx=1200.0, mode=mode, samples_per_pixel=spp,
                        second={"name": "d", "t": (-4.0, 0.0, 0.0)})
    return dataclasses.replace(scene, noise=Noise(sigma=1.0))


def _jobs():
    """Both cameras, both steps, truth and quantisation mixed: every read-back kind in the queue."""
    return [{"camera": "c", "step": 0, "truth": True}, ("d", 1), {"camera": "c", "step": 1, "quantize": True},
            {"camera": "d", "step": 0, "truth": True, "quantize": True}, ("c", 1)]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("mode,spp", [("fast", 1), ("q4", 4), ("exact", 1), ("exact", 4)])
def test_render_many_gives_the_bytes_of_one_render_at_a_time(backend, mode, spp, ctx_for):
    with Renderer(_scene(mode, spp), backend, ctx=ctx_for(backend)) as r:
        single = []
        for job in _jobs():
            args = dict(job) if isinstance(job, dict) else dict(zip(("camera", "step"), job))
            single.append(r.render(**args))
        for depth in (1, 2, 3):
            many = list(r.render_many(_jobs(), depth=depth))
            assert [(x.camera.name, x.step) for x in many] == [(x.camera.name, x.step) for x in single]
            for a, b in zip(many, single):
                same_result(a, b)


CONSTRUCTORS = ("texture", "texture_array", "buffer", "framebuffer", "empty_framebuffer", "vertex_array",
                "depth_renderbuffer", "renderbuffer", "program", "compute_shader")


@pytest.mark.gl
@pytest.mark.parametrize("mode,spp", [("fast", 1), ("exact", 4)])
def test_a_stream_of_frames_makes_no_new_gl_objects(mode, spp, gl_ctx, monkeypatch):
    """After a first pass over the jobs every target, scratch texture, framebuffer, vertex array
    and pack buffer exists: a second pass calls none of the context's constructors."""
    with Renderer(_scene(mode, spp), "gl", ctx=gl_ctx) as r:
        list(r.render_many(_jobs()))
        made = []
        for name in CONSTRUCTORS:
            make = getattr(type(gl_ctx), name)
            monkeypatch.setattr(type(gl_ctx), name,
                                lambda self, *a, _name=name, _make=make, **k: (made.append(_name), _make(self, *a, **k))[1])
        list(r.render_many(_jobs()))
        monkeypatch.undo()
        assert made == []


@pytest.mark.gl
def test_a_stream_stopped_early_collects_what_it_queued(gl_ctx):
    with Renderer(_scene("exact", 1), "gl", ctx=gl_ctx) as r:
        stream = r.render_many(_jobs(), depth=3)
        next(stream)
        stream.close()                          # two frames were still queued
        assert not r.backend.resources.lent
        again = r.render("c", 0, truth=True)    # the renderer goes on as before
        same_result(again, next(iter(r.render_many([{"camera": "c", "step": 0, "truth": True}]))))


def test_depth_below_one_is_refused():
    with Renderer(_scene("exact", 1), "cpu") as r, pytest.raises(SceneError, match="depth"):
        list(r.render_many([("c", 0)], depth=0))


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_renderer_given_a_new_scene_renders_its_cameras_and_options(backend, ctx_for):
    """A library worker swaps a renderer's scene between variants (same mesh and reference):
    the options and cameras a stream keeps per job are the new scene's, not the old one's."""
    first = _scene("exact", 1)
    moved = first.replace(render={"mode": "q4"}, noise={"sigma": 3.0})
    moved = dataclasses.replace(moved, cameras=(moved.cameras[0], dataclasses.replace(moved.cameras[1], fx=1100.0)))
    jobs = [("d", 1), {"camera": "c", "step": 0, "quantize": True}]
    with Renderer(first, backend, ctx=ctx_for(backend)) as r:
        before = list(r.render_many(jobs))
        r.scene = moved
        after = list(r.render_many(jobs))
    with Renderer(moved, backend, ctx=ctx_for(backend)) as fresh:
        for a, b in zip(after, fresh.render_many(jobs)):
            same_result(a, b)
            assert a.options.mode == "q4" and a.camera == b.camera
    assert after[0].camera.fx == 1100.0 and before[0].image.tobytes() != after[0].image.tobytes()


@pytest.mark.both_stages
@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
def test_no_pass_reads_what_it_did_not_write(stage, gl_ctx, monkeypatch):
    """A GPU's new textures and buffers hold whatever their memory held (llvmpipe's hold zeros):
    every image and truth map is the same, bit for bit, when each texture and reserved buffer
    glsim makes starts filled with 0x7F or 0xFF bytes (NaN floats, huge integers) — every mode,
    1 and 4 samples per pixel (mapped and Newton subsamples), lighting, depth of field, noise and
    the camera passes, two cameras and two steps; either pixel stage (a GPU's default is compute)."""
    import moderngl

    from glsim.scene import bulge_scene, demo_effects

    plain = bulge_scene(size=(128, 96), steps=2)
    scenes = (plain, demo_effects(plain).replace(psf={"kind": "gaussian", "sigma": 0.8},
                                                 vignetting={"natural": True}, sensor={"prnu": 1.0, "dsnu": 2.0}))
    options = [{"mode": m, "samples_per_pixel": s} for m in ("exact", "q4", "fast") for s in (1, 4)]
    options.append({"mode": "exact", "samples_per_pixel": 4, "subsamples": "newton"})

    def renders():
        out = []
        for scene in scenes:
            with Renderer(scene, "gl", ctx=gl_ctx) as r:
                r.backend.stage = stage
                for o in options:
                    for cam, step in ((0, 1), (1, 1), (0, 2), (0, 1)):
                        res = r.render(cam, step, truth=True, **o)
                        out += [res.image, res.truth.element, res.truth.xi, res.truth.eta, res.truth.ref_uv]
        return out

    clean = renders()
    made = {name: getattr(moderngl.Context, name) for name in ("texture", "texture_array", "buffer")}
    for fill in (0x7F, 0xFF):
        def filled(name):
            def make(ctx, *args, **kw):
                obj = made[name](ctx, *args, **kw)
                at = 0 if name == "buffer" else 2          # (buffer(data, …); texture(size, components, data, …))
                data = args[at] if len(args) > at else kw.get("data")
                if data is None:
                    obj.write(bytes([fill]) * (obj.size if name == "buffer" else
                                               int(np.prod(obj.size if name == "texture" else obj.size))
                                               * obj.components * int(obj.dtype[1:])))
                return obj
            return make
        for name in made:
            monkeypatch.setattr(moderngl.Context, name, filled(name))
        for a, b in zip(clean, renders()):
            np.testing.assert_array_equal(a, b)   # (NaN where the clean one has NaN)
        monkeypatch.undo()
