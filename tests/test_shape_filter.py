"""The GPU's shape filter (shaders/shape.comp, glsim.backends.gl.geometry.shape_candidates):
once per load step it bounds every element's area and fold from the nodes as uploaded, so that
the host classifies zero-area, tiny and folded elements in numpy (StepGeometry.shape) only
where some element may be one. It must flag every step where numpy finds one — on elements
on either side of each threshold, in float64 and in float32 builds, far from the origin — and
leave clean steps alone (else the per-step classification it saves comes back)."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from glsim.errors import RenderWarning
from glsim.check.shapefilter import CAMERA, classify, grid, mesh, misses, with_element
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen
from glsim.imaging.view import TINY_AREA_REL, ZERO_AREA_REL, mesh_element_areas

pytestmark = pytest.mark.gl


def rectangle(width: float, height: float, z: float = 300.0, x0: float = 50.0):
    return np.array([[x0, 0, z], [x0 + width, 0, z], [x0 + width, height, z], [x0, height, z]])


@pytest.mark.parametrize("z", [300.0, 3e4])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_steps_are_left_alone(gl_ctx, seed, z):
    nodes, quads = grid(seed, z)
    f64, f32, shape = classify(gl_ctx, nodes, quads)
    assert not shape["excluded"].any() and not f64 and not f32


@pytest.mark.parametrize("z", [300.0, 3e4])
@pytest.mark.parametrize("factor", [0.0, 0.5, 1 - 1e-3, 1 + 1e-3, 1.9])
@pytest.mark.parametrize("threshold", [ZERO_AREA_REL, TINY_AREA_REL])
def test_elements_near_the_area_thresholds_are_flagged(gl_ctx, threshold, factor, z):
    """An element of area factor × threshold × the median (numpy's), either side of it: every
    one numpy calls zero-area or tiny is flagged by both builds (those above it may be too: the
    filter bounds the median by a power of two)."""
    base, quads0 = grid(3, z)
    nodes, quads = with_element(base, quads0, rectangle(10.0, 1e-3, z))
    a = mesh_element_areas(nodes, quads)[0]
    median = float(np.median(a[a > 0]))   # (the added element lies below it whatever its size)
    nodes, quads = with_element(base, quads0, rectangle(10.0, factor * threshold * median / 10.0, z))
    f64, f32, shape = classify(gl_ctx, nodes, quads)
    assert shape["excluded"][-1] == (threshold == ZERO_AREA_REL or factor < 1)
    if shape["excluded"].any():
        assert f64 and f32


@pytest.mark.parametrize("z", [300.0, 3e4])
@pytest.mark.parametrize("eps", [-1e-3, -1e-9, 0.0, 1e-9, 1e-3])
def test_elements_near_a_fold_are_flagged(gl_ctx, eps, z):
    """Corner 3 on, just across or just inside the diagonal 0–2 (the second triangle's normal
    against the first's): every element numpy calls folded is flagged by both builds."""
    nodes, quads = grid(4, z)
    corners = np.array([[50.0, 0, z], [60.0, 0, z], [60.0, 10.0, z], [55.0 + eps, 5.0, z]])
    nodes, quads = with_element(nodes, quads, corners)
    f64, f32, shape = classify(gl_ctx, nodes, quads)
    if eps != 0:   # (on the diagonal the sign is numpy's rounding's)
        assert (len(quads) - 1 in shape["folded"]) == (eps > 0)
    if shape["excluded"].any():
        assert f64 and f32


def test_elements_at_float32s_resolution_are_flagged(gl_ctx):
    """Where the float32 build's own rounding decides (glsim.check.shapefilter.
    at_float32_resolution: a tiny element 0.1–10 % below the threshold at a few float32 ulps of
    height under a tight bound on the median, or corner 3 up to a float32 ulp across the
    diagonal), 40 random ones of each kind: every one numpy excludes is flagged by both builds.
    The float32 areas and folds alone miss some of them."""
    missed, found = misses(gl_ctx, 40)
    assert found == 80 and missed == 0


def test_a_clean_mesh_is_not_classified_on_the_host(gl_ctx):
    """Rendering a clean plate's steps with their warnings (all modes) never runs numpy's
    classification; a step with a folded element does, and names it."""
    scene = Scene(cameras=(CAMERA,), specimen=Specimen(plate=Plate(width=60, height=40, nx=6, ny=4,
                                                                translations=((0.5, 0.0, 0.0),)),
                                                    t=(0, 0, 300.0)))
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        for mode in ("fast", "q4", "exact"):
            for step in (0, 1):
                r.render(0, step, mode=mode)
        assert not any(r.geometry.step(step).shape_known for step in (0, 1))
    nodes, quads = grid(5)
    nodes, quads = with_element(nodes, quads, np.array([[50.0, 0, 300], [60, 0, 300], [60, 10, 300], [56, 5, 300]]))
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always", RenderWarning)
        with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh(nodes, quads)) as r:
            r.render(0, 0, mode="exact")
            assert r.geometry.step(0).shape_known
    assert any("folded" in str(w.message) for w in got)
