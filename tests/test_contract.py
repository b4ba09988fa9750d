"""The backend contract (glsim.backends.contract): both backends take the same request and
answer with the same kind of result, name their stages from one vocabulary, and the renderer
asks their capabilities, never their names."""
import ast
import dataclasses
from pathlib import Path

import numpy as np
import pytest

from glsim.backends.contract import STAGES, Capabilities, Raster, Request
from glsim.render import Renderer
from glsim.scene import bulge_scene, demo_effects

BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


def _stage_ok(name: str) -> bool:
    return name in STAGES or name.startswith("blur_")   # GL's blur passes: blur_<scheme>


@pytest.mark.parametrize("backend", BACKENDS)
def test_both_backends_answer_one_request_type(backend, ctx_for):
    scene = demo_effects(bulge_scene(size=(406, 308), steps=1))
    pitch = 30.0 / (6818.0 * 406 / 1624)   # the rig's pixel pitch for its 30 mm lens; f/1 defocuses the bulge
    scene = dataclasses.replace(scene, optics=dataclasses.replace(scene.optics, f_number=1.0, pixel_pitch=pitch))
    with Renderer(scene, backend, ctx=ctx_for(backend)) as r:
        b = r.backend
        assert b.name == backend and isinstance(b.capabilities, Capabilities)
        with pytest.raises(dataclasses.FrozenInstanceError):
            b.capabilities.float64 = False
        view = r.geometry.view(scene.cameras[0], 1)
        out = b.render(Request(view, dataclasses.replace(scene.render, samples_per_pixel=4), truth=True))
        assert isinstance(out, Raster) and out.image.shape == (308, 406) and out.image.dtype == np.float32
        assert set(out.samples) >= {"element", "xi", "eta", "ref_uv"} and out.samples["xi"].dtype == np.float64
        assert out.stages == ("raster", "interpolate", "downsample")   # no effects in a bare request
        res = r.render(0, 1, truth=True)
        assert all(_stage_ok(s) for s in res.stages), res.stages
        order = [STAGES.index("blur" if s.startswith("blur_") else s) for s in res.stages]
        assert order == sorted(order), res.stages      # in the vocabulary's order
        assert {"light", "noise"} <= set(res.stages) and any(s.startswith("blur") for s in res.stages), res.stages


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("spp", [1, 4])
def test_an_unpolished_raster_has_the_same_elements(backend, spp, ctx_for):
    """Request.polish = False (mode fast's Jacobian, which wants only the elements): the raster's
    elements and image as polished, its (ξ, η) the triangles' own (not the material point's)."""
    scene = bulge_scene(size=(96, 72), steps=1)
    with Renderer(scene, backend, ctx=ctx_for(backend)) as r:
        view = r.geometry.view(scene.cameras[0], 1)
        opts = dataclasses.replace(scene.render, mode="fast", samples_per_pixel=spp)
        a, b = (r.backend.render(Request(view, opts, truth=True, polish=p)) for p in (True, False))
    hit = a.samples["element"] >= 0
    assert np.array_equal(a.samples["element"], b.samples["element"]) and hit.sum() > 1000
    assert np.array_equal(a.image, b.image)
    assert not np.array_equal(a.samples["xi"][hit], b.samples["xi"][hit])


def test_the_renderer_asks_capabilities_not_names():
    """glsim/render.py never compares the backend's name."""
    tree = ast.parse((Path(__file__).parents[1] / "glsim" / "render.py").read_text())
    compared = [n for n in ast.walk(tree) if isinstance(n, ast.Compare)
                and any(isinstance(x, ast.Attribute) and x.attr == "backend_name" for x in [n.left, *n.comparators])]
    assert not compared
