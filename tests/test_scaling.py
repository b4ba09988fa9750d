"""Issue 19: per-element work on the GPU, uploaded once; CPU work per view independent of the
element count; the same warnings; bounded footprints of elements that do not project; an
oracle that fits 10⁶ elements in memory.

No timing asserts: the CPU side is checked by what runs (no numpy view per image, uploads per
renderer and per step) and by the memory it allocates per image.
"""
import tracemalloc
import warnings

import numpy as np
import pytest

import glsim.render
import glsim.imaging.geometry
import glsim.imaging.view
from glsim.errors import RenderWarning
from glsim.check import closed_forms, oracle_maps
from glsim.render import Renderer
from glsim.scene import Plate, Scene, Specimen, bulge_scene
from glsim.scene.camera import Camera, Distortion
from glsim.scene.mesh import Mesh
from glsim.imaging.view import cover_rectangles, make_view

from _plates import plate_scene

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

MODES = ("fast", "q4", "exact")


# two cameras a, b (b turned 5° about y, 20 mm to the side) 200 mm from a 60×45 mm plate
STEREO = dict(size=(96, 72), fx=160.0, distortion=Distortion(k1=-0.1), z=200.0, name="a",
              second={"name": "b", "cx": (96 - 1) / 2 + 3, "R": ((0.9961947, 0, -0.0871557), (0, 1, 0), (0.0871557, 0, 0.9961947)),
                      "t": (20.0, 0.0, 0.0)})


def grid(n_side: int, steps: int = 2) -> Plate:
    """The 60×45 mm plate of n_side × n_side elements, moved by (0.1, −0.05, 0) mm per step."""
    return Plate(width=60, height=45, nx=n_side, ny=n_side,
                 translations=tuple((0.1 * k, -0.05 * k, 0.0) for k in range(1, steps)))


class Counter:
    def __init__(self, fn):
        self.fn, self.calls = fn, 0

    def __call__(self, *a, **k):
        self.calls += 1
        return self.fn(*a, **k)


@pytest.mark.gl
def test_gl_path_builds_no_numpy_view_and_uploads_once(gl_ctx, monkeypatch):
    """Rendering on GL runs make_view never (the oracle's per-element numpy work); the mesh is
    uploaded once per renderer and each step's nodes once (per precision), shared by cameras."""
    counters = {}
    for mod in (glsim.render, glsim.imaging.geometry, glsim.imaging.view):
        counters[mod.__name__] = Counter(mod.make_view)
        monkeypatch.setattr(mod, "make_view", counters[mod.__name__])
    cover = Counter(glsim.imaging.view.cover_rectangles)
    monkeypatch.setattr(glsim.imaging.view, "cover_rectangles", cover)
    with Renderer(plate_scene(plate=grid(12), **STEREO), "gl", ctx=gl_ctx) as r:
        for step in (0, 1):
            for cam in (0, 1):
                for mode in MODES:
                    r.render(cam, step, mode=mode)
        buffers = r.backend.geometry
        assert r.geometry.step_builds == 2                    # one StepGeometry per step
        assert buffers.uploads == {"mesh": 2, "step": 4}      # (float32, float64) × (mesh, steps)
        assert buffers.view_passes == 2 * 2 * 2               # q4 and exact: one compute pass per image
    assert all(c.calls == 0 for c in counters.values()) and cover.calls == 0


@pytest.mark.gl
@pytest.mark.parametrize("flat", [False, True])
def test_lighting_normals_once_per_step_not_per_view(gl_ctx, monkeypatch, flat):
    """With lighting, GL takes the corner normals once per load step (world frame, rotated on the
    GPU): no per-view numpy normals, and the lit image still equals the oracle's."""
    import dataclasses

    import glsim.effects
    from glsim.scene import demo_effects

    lit = demo_effects(bulge_scene(size=(203, 154), steps=1))
    scene = dataclasses.replace(lit, optics=None, noise=None,
                                lighting=dataclasses.replace(lit.lighting, normals="flat" if flat else "smooth"))
    per_view = Counter(glsim.effects.corner_normals)
    monkeypatch.setattr(glsim.effects, "corner_normals", per_view)
    with Renderer(scene, "gl", ctx=gl_ctx) as g:
        images = [g.render(cam, 1).image for cam in (0, 1)]
        ties = [oracle_maps.renderer_ties(g, scene.render.mode, cam, 1) for cam in (0, 1)]
        assert per_view.calls == 0 and g.geometry.step_builds == 1
        assert g.backend.geometry.uploads["step"] == 2          # nodes and normals, once
    mode = scene.render.mode
    with Renderer(scene, "cpu") as c:
        for cam, a, tie in zip((0, 1), images, ties):   # within the lit image's bound but at coverage ties
            over = np.abs(a.astype(float) - c.render(cam, 1).image) > oracle_maps.renderer_lit(c, mode, cam, 1)
            assert not (over & ~tie).any()


@pytest.mark.gl
@pytest.mark.parametrize("mode", MODES)
def test_cpu_memory_per_image_does_not_grow_with_the_mesh(gl_ctx, mode):
    """What the CPU allocates to render one more image of an uploaded step: the same for 144
    and 20,736 elements (the image and a few small arrays), not a per-element array."""
    peaks = []
    for n in (12, 144):
        with Renderer(plate_scene(plate=grid(n), **STEREO), "gl", ctx=gl_ctx) as r:
            r.render(0, 1, mode=mode)                           # step uploaded, programs built
            r.render(1, 1, mode=mode)
            tracemalloc.start()
            r.render(1, 1, mode=mode)
            peaks.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
    W, H = 96, 72
    assert peaks[1] < peaks[0] + 64 * 1024, peaks            # 20,592 more elements: < 3 bytes each
    assert peaks[1] < 8 * W * H + 256 * 1024, peaks


def problem_mesh():
    """A mesh with every kind of named element: zero area, tiny, folded, grazing, crossing the
    camera plane at step 1, and beyond the distortion's valid radius."""
    x, y = np.meshgrid(np.linspace(-30, 30, 7), np.linspace(-20, 20, 5))
    nodes = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, 300.0)])
    idx = np.arange(x.size).reshape(x.shape)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], -1).reshape(-1, 4)
    n = len(nodes)
    extra = np.array([[0, 0, 300.0], [5, 0, 300.0], [5, 1e-5, 300.0], [0, 1e-5, 300.0],    # tiny
                      [-5, -5, 300.0], [5, -5, 300.0], [-5, 5, 300.0], [5, 5, 300.0],      # bow-tie
                      [-5, 0, 300.0], [5, 0, 300.0], [5, 0, 330.0], [-5, 0, 330.0],        # edge-on
                      [400, 0, 300.0], [600, 0, 300.0], [600, 200, 300.0], [400, 200, 300.0]])  # far out
    nodes = np.vstack([nodes, extra])
    quads = np.vstack([quads, [[n, n, n, n], [0, 1, 2, 2]], n + np.arange(16).reshape(4, 4)[[0, 1]],
                       [[n + 4, n + 5, n + 7, n + 6]], n + np.arange(16).reshape(4, 4)[[2, 3]]])
    moved = nodes.copy()
    moved[:7, 2] = -50.0                                  # step 1: the first row crosses the camera plane
    return nodes, quads, moved


@pytest.mark.gl
@pytest.mark.parametrize("mode", MODES)
def test_gl_warnings_name_the_same_elements_as_make_view(gl_ctx, mode):
    nodes, quads, moved = problem_mesh()
    cam = Camera(name="c", size=(120, 90), fx=100.0, fy=100.0, cx=59.5, cy=44.5, distortion=Distortion(k1=-0.3))
    mesh = Mesh(nodes=nodes, quads=quads, node_labels=np.arange(1, len(nodes) + 1),
                element_labels=np.arange(501, 501 + len(quads)), displacements=(np.zeros_like(nodes), moved - nodes))
    scene = Scene(cameras=(cam,), specimen=Specimen(plate=Plate()))
    for step, deformed in ((0, nodes), (1, moved)):
        with warnings.catch_warnings(record=True) as want:
            warnings.simplefilter("always", RenderWarning)
            with Renderer(scene, "cpu", mesh=mesh) as c:
                make_view(cam, c.reference.camera, nodes, deformed, quads, mesh.element_labels)
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always", RenderWarning)
            with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as g:
                # the markers were cleared: the same again
                for _ in range(3):
                    g.render(0, step, mode=mode)
        expected = [str(w.message) for w in want]
        messages = [str(w.message) for w in got if "outside the reference" not in str(w.message)]
        assert len(expected) >= 4 and messages == expected * 3, (step, messages, expected)
        for what in ("zero area", "tiny", "folded", "grazing", "valid radius"):
            assert any(what in m for m in expected), what


def barrel_scene(width: float):
    """Barrel distortion whose valid radius lies inside the image (k1 = −0.35, fx = 60 px): a
    600 mm plate at 100 mm has 448 of its 484 elements beyond it; a 150 mm one none."""
    cam = Camera(name="c", size=(160, 120), fx=60.0, fy=60.0, cx=79.5, cy=59.5, distortion=Distortion(k1=-0.35))
    plate = Plate(width=width, height=0.75 * width, nx=22, ny=22, translations=((0.37, -0.21, 0.0),))
    return Scene(cameras=(cam,), specimen=Specimen(plate=plate, t=(0, 0, 100.0)))


@pytest.mark.parametrize("backend", ["cpu", pytest.param("gl", marks=pytest.mark.gl)])
def test_unprojectable_elements_have_bounded_footprints(backend, request):
    """Issue 17 item 6: elements beyond the valid radius are tested only where their rays can
    be (inside the valid radius), not against the whole image: the pixel boxes of the 448
    unprojectable elements add up to a few image areas (the whole image each before), and the
    image equals the oracle's."""
    scene = barrel_scene(600.0)
    ctx = request.getfixturevalue("gl_ctx") if backend == "gl" else None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, backend, ctx=ctx) as r:
            view = r.view(0, 1)
            res = r.render(0, 1, mode="exact", truth=True)
        with Renderer(scene, "cpu") as c:
            ref = c.render(0, 1, mode="exact", truth=True)
    bad = ~view.projectable
    assert bad.sum() == 448
    b = view.bbox[bad]
    area = (np.maximum(b[:, 2] - b[:, 0] + 1, 0) * np.maximum(b[:, 3] - b[:, 1] + 1, 0)).sum()
    assert area < 4 * 160 * 120, area
    assert np.array_equal(res.truth.mask, ref.truth.mask)
    assert np.array_equal(res.truth.element, ref.truth.element)


def test_footprints_contain_every_covered_pixel():
    """The bounded covers are conservative: every pixel the oracle's element map gives to an
    element lies in that element's pixel box (barrel case and camera-plane crossing)."""
    from test_render import crossing_scene

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        cases = [(barrel_scene(600.0), None, 1)]
        scene, mesh = crossing_scene()
        cases.append((scene, mesh, 1))
        for scene, mesh, step in cases:
            with Renderer(scene, "cpu", mesh=mesh) as r:
                view = r.view(0, step)
                t = r.render(0, step, mode="exact", truth=True).truth
            v, u = np.nonzero(t.mask)
            box = view.bbox[t.element[v, u]]
            assert ((u >= box[:, 0]) & (u <= box[:, 2]) & (v >= box[:, 1]) & (v <= box[:, 3])).all()
            assert (~view.projectable).any()


@pytest.mark.gl
@pytest.mark.parametrize("scene_name", ["bulge", "barrel"])
def test_gpu_covers_equal_the_numpy_twin(gl_ctx, scene_name):
    """shaders/view.glsl computes the same cover rectangles as glsim.imaging.view (float32
    rounding apart)."""
    scene = bulge_scene(size=(203, 154), steps=1) if scene_name == "bulge" else barrel_scene(600.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, "gl", ctx=gl_ctx) as r:
            r.render(0, 1, mode="exact")
            M = len(r.mesh.quads)
            gpu = np.frombuffer(r.backend.geometry._bufs["cover"].read(), np.float32).reshape(M, 4, 2)
            view = r.view(0, 1)
    seen = view.bbox[:, 2] >= view.bbox[:, 0]
    assert seen.sum() >= 80
    assert np.abs(gpu[seen] - view.cover[seen]).max() < 1e-3


def test_covers_are_computed_in_bounded_memory():
    """cover_rectangles works in chunks: 10⁵ elements need a few tens of MB, not the ~1 GB of
    sampling every element at once."""
    M = 100_000
    rng = np.random.default_rng(0)
    corners = np.array([[0, 0, 0], [0.3, 0, 0], [0.3, 0.3, 0], [0, 0.3, 0]])
    Xd = rng.uniform([-40, -30, 300], [40, 30, 300], (M, 1, 3)) + corners
    cam = Camera(name="c", size=(400, 300), fx=1000.0, fy=1000.0, cx=199.5, cy=149.5, distortion=Distortion(k1=-0.2))
    tracemalloc.start()
    rect, box = cover_rectangles(cam, Xd, np.ones(M, bool), np.zeros(M, bool))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 80e6, peak
    assert (box[:, 2] >= box[:, 0]).mean() > 0.9


def stacked_plates(layers: int):
    """``layers`` plates stacked 7 mm apart in depth, each a little larger than the one in
    front: their pixels have up to ``layers`` candidates (the lists hold 8)."""
    from test_render import custom_mesh_scene, grid_nodes

    nodes, quads = [], []
    for k in range(layers):
        n, q = grid_nodes(4, 3, 40 - 2 * k, 30 - 2 * k, 300.0 + 7 * (layers - 1 - k))
        quads.append(q + sum(len(x) for x in nodes))
        nodes.append(n)
    return custom_mesh_scene(np.vstack(nodes), np.vstack(quads))


@pytest.mark.gl
@pytest.mark.parametrize("stage", ["fragment", "compute"])
@pytest.mark.parametrize("layers", [6, 12])
@pytest.mark.parametrize("mode", ["exact", "q4"])
def test_candidate_lists_and_their_overflow_give_the_oracle(gl_ctx, mode, layers, stage):
    """Pixels with several candidates (resolve.frag or .comp) and with more than the lists hold
    (the fallback over the cover rectangles) show the nearest layer, as the oracle, in either
    pixel stage: the same mask; elements differ only on the coverage ties (pixel centres on a
    shared edge, within float64's tie distance, oracle_maps.renderer_ties), both giving the same
    point; grey levels within the mode's bound (oracle_maps.renderer_grey) off the ties."""
    scene, mesh = stacked_plates(layers)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RenderWarning)
        with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as g, Renderer(scene, "cpu", mesh=mesh) as c:
            g.backend.stage = stage
            a = g.render(0, 0, truth=True, mode=mode)
            flags = g.backend.geometry.list_flags(*scene.cameras[0].size)   # pass 1's draws of the last view
            b = c.render(0, 0, truth=True, mode=mode)
            ties = agree_off_ties(g, c, a, b, mode)
    assert flags == (True, layers > 8)
    assert a.truth.mask.sum() > 5000 and ties.sum() < 0.2 * a.truth.mask.sum()


def agree_off_ties(g, c, a, b, mode):
    """GL's render ``a`` (renderer ``g``, camera 0, step 0, 1 spp) and the oracle's ``b``
    (renderer ``c``): the same mask; elements differing only on the coverage ties
    (oracle_maps.renderer_ties), both giving the same point there; grey levels within
    oracle_maps.renderer_grey off the ties. Returns the ties."""
    ties = oracle_maps.renderer_ties(g, mode, 0, 0)
    grey = oracle_maps.renderer_grey(c, mode, 0, 0, 1, closed_forms.FLOAT64, b.truth)
    assert np.array_equal(a.truth.mask, b.truth.mask)
    differ = a.truth.element != b.truth.element
    assert np.abs(a.truth.X_deformed[differ] - b.truth.X_deformed[differ]).max(initial=0) <= closed_forms.FLOAT64
    assert not (differ & ~ties).any()
    assert not ((np.abs(a.image.astype(float) - b.image) > grey) & ~ties).any()
    return ties


@pytest.mark.gl
@pytest.mark.parametrize("mode", ["exact", "q4"])
def test_elements_too_large_for_one_invocation_are_listed_by_their_covers(gl_ctx, mode):
    """candidates.comp lists each element from one invocation and leaves boxes over
    BIN_MAX_SIDE (192) px on a side to the cover triangles (exact.vert BIG_ONLY): one 300 px
    element in front of 108 small ones, both listings in one view, against the oracle."""
    from test_render import custom_mesh_scene, grid_nodes

    # (sizes that put no outline on a row or column of pixel centres)
    big_n, big_q = grid_nodes(1, 1, 60.3, 45.3, 300.0)         # one element, ~300×225 px
    small_n, small_q = grid_nodes(12, 9, 80.7, 60.7, 310.0)    # 108 elements of ~32 px behind it
    scene, mesh = custom_mesh_scene(np.vstack([big_n, small_n]), np.vstack([big_q, small_q + len(big_n)]),
                                    size=(480, 360))
    with Renderer(scene, "gl", ctx=gl_ctx, mesh=mesh) as g, Renderer(scene, "cpu", mesh=mesh) as c:
        a = g.render(0, 0, truth=True, mode=mode)
        b = c.render(0, 0, truth=True, mode=mode)
        built = [d for files, d in g.backend.programs.compiled if files == ("exact.vert", "candidates.frag")]
        agree_off_ties(g, c, a, b, mode)   # elements differ only at ties on shared edges: the same point either way
    assert built == [{"BIG_ONLY": None}]
    assert (a.truth.element == 0).sum() > 50_000


@pytest.mark.tools
@pytest.mark.slow
@pytest.mark.gl
def test_bench_scaling_reduced_run_writes_elsewhere(tmp_path, capsys, gl_ctx):
    """A reduced `glsim bench scaling` runs end to end (each point in its own process) and
    writes where it is told; aimed at bench/results it is refused before anything runs."""
    import json

    from glsim.backends.gl.context import software_renderer
    from glsim.backends.gl.plan import environment_stage, pixel_stage
    from glsim.bench import cli

    # the pixel stage its processes get on this driver (the passes are named by their shaders)
    ext = {"fragment": "frag", "compute": "comp"}[environment_stage() or pixel_stage(software_renderer(gl_ctx))]

    assert cli.main(["scaling", "--elements", "50", "--out", str(cli.RESULTS)]) == 2
    assert "--out bench/results" in capsys.readouterr().err
    assert cli.results_dir(None, full=False, command="scaling") == cli.SCRATCH
    rc = cli.main(["scaling", "--elements", "20", "300", "--sizes", "96x72", "--size-elements", "40",
                         "--reps", "1", "--no-oracle", "--out", str(tmp_path)])
    assert rc == 0
    report = json.loads((tmp_path / "scaling.json").read_text())
    assert [r["elements"] for r in report["elements"]] == [20, 300] and report["sizes"][0]["size"] == [96, 72]
    for r in report["elements"] + report["sizes"]:
        for mode in ("fast", "q4", "exact"):
            row = r["renderers"][mode]
            assert row["median_s"] > 0 and row["host_ms"] >= 0 and row["coverage"] > 0.3
            # the render timed pass by pass: every pass named by its shader, within its wall time
            assert 0 < sum(row["passes"].values()) <= row["passes_wall_s"]
        assert {"view.comp", "candidates.comp", f"classify.{ext}", f"single.{ext}"} <= set(r["renderers"]["exact"]["passes"])
        assert set(r["renderers"]["fast"]["passes"]) == ({"fast_ids.frag", "fast_shade.comp"} if ext == "comp"
                                                         else {"fast.frag"})
        assert r["peak_rss_mb"] > 0
    assert [g["met"] for g in report["goals"]][:3] == [None, None, None]   # 128k and 2k not measured
    md = (tmp_path / "scaling.md").read_text()
    assert md.startswith("# glsim scaling benchmark") and "| 300 | " in md.split("## Where the time goes (exact")[1]


@pytest.mark.gl
def test_load_steps_evicted_and_coming_back(gl_ctx):
    """Going round more load steps than are kept, twice: each step's buffers are made again
    when it comes back, and every image equals a fresh renderer's."""
    scene = plate_scene(plate=grid(12, steps=4), **STEREO)
    with Renderer(scene, "gl", ctx=gl_ctx) as r:
        first = [r.render(0, k, mode="exact").image for k in range(4)]
        again = [r.render(0, k, mode=m).image for k in range(4) for m in ("exact", "fast")][::2]
        assert r.geometry.step_builds == 8
    for a, b in zip(first, again):
        assert np.array_equal(a, b)
    with Renderer(scene, "gl", ctx=gl_ctx) as fresh:
        assert np.array_equal(fresh.render(0, 3, mode="exact").image, again[3])
