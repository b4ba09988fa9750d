"""The GL backend as an executor: nothing of one render carries over into another but what the
request names — the same bytes whatever ran before on the renderer, or on another renderer
sharing the context's programs, and whatever scene object a renderer is given next."""
import copy
import dataclasses
import warnings

import numpy as np
import pytest

from glsim.render import Renderer
from glsim.scene import Lighting, Noise
from _plates import plate_scene, same_result

pytestmark = pytest.mark.gl

# kinds that share programs whose uniforms differ (candidates.comp's u_half at 1 and 4 spp),
# with truth and without, quantised on the GPU or not, Newton's sub-samples
KINDS = [{"mode": "exact", "samples_per_pixel": 1, "truth": True}, {"mode": "exact", "samples_per_pixel": 4},
         {"mode": "q4", "samples_per_pixel": 4, "truth": True, "quantize": True},
         {"mode": "fast", "samples_per_pixel": 1, "quantize": True},
         {"mode": "exact", "samples_per_pixel": 4, "subsamples": "newton", "quantize": True}]


def _two_cameras(**kw):
    return plate_scene((96, 72), fx=1200.0, second={"name": "d", "t": (-4.0, 0.0, 0.0)}, **kw)


@pytest.mark.parametrize("lit", [False, True])
def test_interleaved_kinds_give_the_bytes_of_each_rendered_alone(gl_ctx, lit):
    """Every kind, camera and step in turn, twice, on one renderer (pipelined), while a second
    renderer on the same context writes the shared programs' uniforms in between: each image
    and truth is that of the job rendered on a fresh renderer."""
    scene = _two_cameras(lighting=Lighting() if lit else None)
    jobs = [{"camera": c, "step": step, **kind} for kind in KINDS for c in ("c", "d") for step in (0, 1)]
    with Renderer(scene, "gl", ctx=gl_ctx) as r, Renderer(scene, "gl", ctx=gl_ctx) as other:
        for _ in range(2):
            for job, got in zip(jobs, r.render_many(jobs)):
                other.render(**{**job, "camera": "d" if job["camera"] == "c" else "c"})
                with Renderer(scene, "gl", ctx=gl_ctx) as alone:
                    same_result(got, alone.render(**job))


def test_a_renderer_given_a_new_scene_renders_that_scene(gl_ctx):
    """New lights, and a library's next variant (equal cameras and options, new objects, other
    noise): the images are those of a renderer made for each scene."""
    scene = plate_scene((96, 72), fx=1200.0, lighting=Lighting())
    brighter = dataclasses.replace(scene, lighting=dataclasses.replace(scene.lighting, ambient=0.5))
    with Renderer(scene, "gl", ctx=gl_ctx) as r, Renderer(brighter, "gl", ctx=gl_ctx) as ref:
        for _ in range(2):
            r.render("c", 0)
        r.scene = brighter
        same_result(r.render("c", 0), ref.render("c", 0))
    base = dataclasses.replace(_two_cameras(), noise=Noise(sigma=1.0))
    jobs = [{"camera": c, "step": s, "truth": True, "quantize": True} for c in ("c", "d") for s in (0, 1)]
    with Renderer(base, "gl", ctx=gl_ctx) as r:
        for k in range(2):
            variant = copy.deepcopy(dataclasses.replace(base, noise=Noise(sigma=1.0 + k)))
            r.scene = variant
            with Renderer(variant, "gl", ctx=gl_ctx) as alone:
                for a, b in zip(r.render_many(jobs), alone.render_many(jobs)):
                    same_result(a, b)


def test_a_time_series_warns_and_renders_each_step_as_alone(gl_ctx):
    """Each load step of a series drawn once, lit, with an element that collapses at one step
    (excluded: its flag differs from the other steps'): images, truth and warnings are those of
    each step rendered on a fresh renderer."""
    from glsim.scene.mesh import Mesh
    from test_render import custom_mesh_scene, grid_nodes

    nodes, quads = grid_nodes(8, 6, 20.0, 15.0, 300.0)
    steps = [np.zeros_like(nodes)]
    for k in range(1, 4):
        u = np.zeros_like(nodes)
        u[:, 0], u[:, 1] = 0.3 * k, -0.1 * k * nodes[:, 0] / 10.0
        if k == 2:   # element 0 collapses onto its first node (zero area: excluded)
            u[quads[0]] = u[quads[0, 0]] + nodes[quads[0, 0]] - nodes[quads[0]]
        steps.append(u)
    scene, _ = custom_mesh_scene(nodes, quads, size=(96, 72), fx=1200.0)
    scene = dataclasses.replace(scene, lighting=Lighting())
    mesh = Mesh(nodes=nodes, quads=quads, node_labels=np.arange(1, len(nodes) + 1),
                element_labels=np.arange(101, 101 + len(quads)), displacements=tuple(steps))
    kinds = [{"mode": "exact", "truth": True}, {"mode": "q4", "samples_per_pixel": 4, "quantize": True},
             {"mode": "fast", "quantize": True}]
    jobs = [{"camera": "c", "step": k, **kind} for k in range(4) for kind in kinds]

    def warned(render):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            out = render()
        return out, sorted(str(w.message) for w in seen)

    with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as r:
        got, got_warned = warned(lambda: list(r.render_many(jobs)))
    want, want_warned = [], []
    for job in jobs:
        with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as alone:
            out, w = warned(lambda: alone.render(**job))
        want.append(out)
        want_warned += w
    for a, b in zip(got, want):
        same_result(a, b)
    assert got_warned == sorted(want_warned) and any("zero area" in w for w in got_warned)
