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

from glsim.backends.gl.geometry import GeometryBuffers, shape_candidates
from glsim.backends.gl.programs import ProgramCache
from glsim.errors import RenderWarning
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen
from glsim.scene.camera import Camera
from glsim.scene.mesh import Mesh
from glsim.stages.geometry import MeshGeometry
from glsim.stages.view import TINY_AREA_REL, ZERO_AREA_REL

pytestmark = pytest.mark.gl

CAM = Camera(name="c", size=(96, 72), fx=100.0, fy=100.0, cx=47.5, cy=35.5)


def grid(seed: int, z: float = 300.0, jitter: float = 1.0):
    """A 7 × 5 grid of 10 mm elements at depth ``z`` (mm), its inner nodes moved by up to
    ``jitter`` mm: nodes (N, 3), quads (M, 4)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(8) * 10.0 - 35.0, np.arange(6) * 10.0 - 25.0)
    nodes = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    inner = (np.abs(x.ravel()) < 35) & (np.abs(y.ravel()) < 25)
    nodes[inner, :2] += rng.uniform(-jitter, jitter, (inner.sum(), 2))
    nodes[:, 2] += rng.uniform(-jitter, jitter, len(nodes))
    idx = np.arange(x.size).reshape(x.shape)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    return nodes, quads


def mesh(nodes, quads) -> Mesh:
    return Mesh(nodes, quads, np.arange(1, len(nodes) + 1), np.arange(1, len(quads) + 1))


def with_element(nodes, quads, corners):
    """The mesh with one more element on its own four nodes ``corners`` (4, 3)."""
    n = len(nodes)
    return np.vstack([nodes, corners]), np.vstack([quads, n + np.arange(4)])


def filter_and_numpy(ctx, nodes, quads):
    """(candidates from the float64 build, from the float32 build, numpy's classification)."""
    geo = MeshGeometry(mesh(nodes, quads), CAM)
    view = geo.view(CAM, 0)
    buffers = GeometryBuffers(ctx, ProgramCache(ctx), geo)
    try:
        found = [shape_candidates(np.frombuffer(buffers._step_buffers(view, fp64)[1].read(), np.uint32), len(quads))
                 for fp64 in (True, False)]
    finally:
        buffers.release()
    return found[0], found[1], view.step_geo.shape()


def rectangle(width: float, height: float, z: float = 300.0, x0: float = 50.0):
    return np.array([[x0, 0, z], [x0 + width, 0, z], [x0 + width, height, z], [x0, height, z]])


@pytest.mark.parametrize("z", [300.0, 3e4])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_steps_are_left_alone(gl_ctx, seed, z):
    nodes, quads = grid(seed, z)
    f64, f32, shape = filter_and_numpy(gl_ctx, nodes, quads)
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
    a = _areas(nodes, quads)
    median = float(np.median(a[a > 0]))   # (the added element lies below it whatever its size)
    nodes, quads = with_element(base, quads0, rectangle(10.0, factor * threshold * median / 10.0, z))
    f64, f32, shape = filter_and_numpy(gl_ctx, nodes, quads)
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
    f64, f32, shape = filter_and_numpy(gl_ctx, nodes, quads)
    if eps != 0:   # (on the diagonal the sign is numpy's rounding's)
        assert (len(quads) - 1 in shape["folded"]) == (eps > 0)
    if shape["excluded"].any():
        assert f64 and f32


@pytest.mark.parametrize("kind", ["tiny", "fold"])
def test_elements_at_float32s_resolution_are_flagged(gl_ctx, kind):
    """Where the float32 build's own rounding decides: a grid whose median area lies just below
    a power of two (64 mm²: the filter's bound on the median is then tight), and one element
    either tiny by 0.1–10 % less than the threshold, placed where float32 resolves its height
    to a few ulps, or with corner 3 a few float32 ulps across the diagonal; 40 random ones
    each. The float32 areas and folds alone miss some of them: the bounds must flag them all."""
    rng = np.random.default_rng(7)
    flagged = 0
    for _ in range(40):
        x, y = np.meshgrid(np.arange(8) * 8.0 - 28.0, np.arange(6) * 7.999875 - 20.0)
        nodes = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 300.0)])
        idx = np.arange(x.size).reshape(x.shape)
        quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
        x0, y0 = rng.uniform(30.0, 40.0), rng.uniform(3.0, 9.0)
        if kind == "tiny":
            h = rng.uniform(0.9, 0.999) * TINY_AREA_REL * 8.0 * 7.999875 / 10.0
            corners = np.array([[x0, y0, 300], [x0 + 10, y0, 300], [x0 + 10, y0 + h, 300], [x0, y0 + h, 300]])
        else:
            t = rng.uniform(0.05, 1.0) * 2.0 ** -19   # up to a float32 ulp of the local coordinates (≤ 32 mm)
            corners = np.array([[x0, y0, 300], [x0 + 10, y0, 300], [x0 + 10, y0 + 10, 300],
                                [x0 + 5 + t, y0 + 5 - t, 300]])
        nodes, quads = with_element(nodes, quads, corners)
        f64, f32, shape = filter_and_numpy(gl_ctx, nodes, quads)
        assert shape["excluded"][-1]
        flagged += f64 and f32
    assert flagged == 40


def _areas(nodes, quads):
    from glsim.stages.view import mesh_element_areas

    return mesh_element_areas(nodes, quads)[0]


def test_a_clean_mesh_is_not_classified_on_the_host(gl_ctx):
    """Rendering a clean plate's steps with their warnings (all modes) never runs numpy's
    classification; a step with a folded element does, and names it."""
    scene = Scene(cameras=(CAM,), specimen=Specimen(plate=Plate(width=60, height=40, nx=6, ny=4,
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
