"""The GPU's shape filter (shaders/shape.comp, glsim.backends.gl.geometry.shape_candidates)
against numpy's classification of zero-area, tiny and folded elements
(glsim.imaging.geometry.StepGeometry.shape) on small meshes with one hard element, for
``glsim check`` and tests/test_shape_filter.py. The filter must flag every step in which numpy
finds such an element, in float64 and float32 builds; a step it does not flag is never
classified on the host."""
from __future__ import annotations

import numpy as np

from glsim.scene.camera import Camera
from glsim.scene.mesh import Mesh
from glsim.imaging.view import TINY_AREA_REL

CAMERA = Camera(name="c", size=(96, 72), fx=100.0, fy=100.0, cx=47.5, cy=35.5)
GRID_AREA = 8.0 * 7.999875   # the float32-resolution grid's element area (mm²): just below 2^6


def grid(seed: int, z: float = 300.0, jitter: float = 1.0, pitch=(10.0, 10.0)):
    """A 7 × 5 grid of elements of ``pitch`` (mm) at depth ``z`` (mm), its inner nodes moved by
    up to ``jitter`` mm: nodes (N, 3), quads (M, 4)."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(8) * pitch[0] - 3.5 * pitch[0], np.arange(6) * pitch[1] - 2.5 * pitch[1])
    nodes = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])
    inner = (np.abs(x.ravel()) < 3.5 * pitch[0]) & (np.abs(y.ravel()) < 2.5 * pitch[1])
    nodes[inner, :2] += rng.uniform(-jitter, jitter, (inner.sum(), 2))
    nodes[:, 2] += rng.uniform(-jitter, jitter, len(nodes))
    idx = np.arange(x.size).reshape(x.shape)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    return nodes, quads


def mesh(nodes: np.ndarray, quads: np.ndarray) -> Mesh:
    return Mesh(nodes, quads, np.arange(1, len(nodes) + 1), np.arange(1, len(quads) + 1))


def with_element(nodes: np.ndarray, quads: np.ndarray, corners: np.ndarray):
    """The mesh with one more element on its own four nodes ``corners`` (4, 3)."""
    n = len(nodes)
    return np.vstack([nodes, corners]), np.vstack([quads, n + np.arange(4)])


def classify(ctx, nodes: np.ndarray, quads: np.ndarray):
    """(the float64 build's filter flags the step, the float32 build's, numpy's classification)
    for step 0 of the mesh on GL context ``ctx``."""
    from glsim.backends.gl.geometry import GeometryBuffers, shape_candidates
    from glsim.backends.gl.programs import ProgramCache
    from glsim.imaging.geometry import MeshGeometry

    geo = MeshGeometry(mesh(nodes, quads), CAMERA)
    view = geo.view(CAMERA, 0)
    buffers = GeometryBuffers(ctx, ProgramCache(ctx), geo)
    try:
        found = [shape_candidates(np.frombuffer(buffers.shape_buffer(view, fp64).read(), np.uint32), len(quads))
                 for fp64 in (True, False)]
    finally:
        buffers.release()
    return found[0], found[1], view.step_geo.shape()


def at_float32_resolution(kind: str, rng):
    """A grid whose median area lies just below a power of two (GRID_AREA; the filter's bound on
    the median is then tight) with one element where float32's rounding decides: "tiny", 0.1–10 %
    below the threshold, placed where float32 resolves its height to a few ulps; or "fold",
    corner 3 up to a float32 ulp of the local coordinates across the diagonal 0–2."""
    nodes, quads = grid(0, jitter=0.0, pitch=(8.0, 7.999875))
    x0, y0 = rng.uniform(30.0, 40.0), rng.uniform(3.0, 9.0)
    if kind == "tiny":
        h = rng.uniform(0.9, 0.999) * TINY_AREA_REL * GRID_AREA / 10.0
        corners = np.array([[x0, y0, 300], [x0 + 10, y0, 300], [x0 + 10, y0 + h, 300], [x0, y0 + h, 300]])
    else:
        t = rng.uniform(0.05, 1.0) * 2.0 ** -19   # up to a float32 ulp of the local coordinates (≤ 32 mm)
        corners = np.array([[x0, y0, 300], [x0 + 10, y0, 300], [x0 + 10, y0 + 10, 300],
                            [x0 + 5 + t, y0 + 5 - t, 300]])
    return with_element(nodes, quads, corners)


def misses(ctx, n: int = 20, seed: int = 7) -> tuple[int, int]:
    """Over ``n`` meshes of each kind of :func:`at_float32_resolution`: (the steps numpy finds an
    excluded element in that either build's filter does not flag, the steps numpy finds one in)."""
    rng = np.random.default_rng(seed)
    missed = found = 0
    for kind in ("tiny", "fold"):
        for _ in range(n):
            f64, f32, shape = classify(ctx, *at_float32_resolution(kind, rng))
            if shape["excluded"].any():
                found += 1
                missed += not (f64 and f32)
    return missed, found
