"""A closed Renderer refuses to render, by name, on both backends: GL's objects are released
(moderngl used to fail inside with an AttributeError of its InvalidObject) and the CPU oracle
used to render on regardless."""
import pytest

from glsim.errors import GlsimError, RendererClosedError
from glsim.render import Renderer

from _plates import plate_scene

BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


def closed(backend, ctx_for):
    """A renderer of the small plate that rendered one image, then closed as a `with` block ends."""
    with Renderer(plate_scene(size=(40, 30)), backend, ctx=ctx_for(backend)) as r:
        assert r.render("c", step=1).image.shape == (30, 40)   # open: it renders
    return r


def refused(call):
    with pytest.raises(RendererClosedError, match="this renderer is closed") as info:
        call()
    assert isinstance(info.value, GlsimError)   # what the command line reports without a traceback
    assert "new Renderer" in str(info.value)    # and the fix


@pytest.mark.parametrize("backend", BACKENDS)
def test_render_after_close_is_refused(backend, ctx_for):
    r = closed(backend, ctx_for)
    refused(lambda: r.render("c", step=1))
    refused(lambda: r.render("c", step=1, truth=True, quantize=True))
    refused(lambda: r.render("c", step=1, jacobian=True))


@pytest.mark.parametrize("backend", BACKENDS)
def test_render_many_after_close_is_refused(backend, ctx_for):
    r = closed(backend, ctx_for)
    refused(lambda: list(r.render_many([("c", 0), ("c", 1)])))
    refused(lambda: list(r.render_many([])))   # even with nothing to render


@pytest.mark.parametrize("backend", BACKENDS)
def test_closing_between_render_many_results_stops_it(backend, ctx_for):
    r = Renderer(plate_scene(size=(40, 30)), backend, ctx=ctx_for(backend))
    results = r.render_many([("c", 0), ("c", 1), ("c", 0), ("c", 1)], depth=1)
    assert next(results).step == 0
    r.close()
    refused(lambda: next(results))


@pytest.mark.parametrize("backend", BACKENDS)
def test_sub_frames_after_close_is_refused(backend, ctx_for):
    scene = plate_scene(size=(40, 30))
    scene = scene.replace(exposure={"time": 0.01, "samples": 2, "velocity": [1.0, 0.0, 0.0]})
    with Renderer(scene, backend, ctx=ctx_for(backend)) as r:
        assert len(list(r.sub_frames("c", 0))) == 2
    refused(lambda: list(r.sub_frames("c", 0)))
