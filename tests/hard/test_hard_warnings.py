"""Hard cases (issue 17): warnings name each problem element once, with thresholds relative
to the mesh's median element, and dropped pixels are counted."""
import warnings

import numpy as np
import pytest
from _shapes import custom, grid_mesh

from glsim.errors import RenderWarning
from glsim.render import Renderer
from glsim.scene.camera import Camera

CAM = Camera(name="c", size=(96, 72), fx=1500.0, fy=1500.0, cx=47.5, cy=35.5)


def render_warnings(nodes, quads, backend="cpu", ctx=None, **opts):
    scene, mesh = custom(nodes, quads, CAM)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always", RenderWarning)
        with Renderer(scene, backend, ctx=ctx, mesh=mesh) as r:
            res = r.render(0, 0, truth=True, **opts)
    return res, [str(w.message) for w in rec if issubclass(w.category, RenderWarning)]


def test_tiny_element_named_relative_to_median_and_bow_tie_named_once():
    """An element of 1e-9 of its neighbours' area is named as tiny (an absolute threshold
    would miss it on a large mesh), and a bow-tie seen at a grazing angle only as folded."""
    xs = np.array([-6.0, -2.0, -2.0 + 1e-9 * 4, 2.0, 6.0]) * 10   # column 2: 1e-9 of the others
    nodes, quads = grid_mesh(xs, np.array([-4.0, 0.0, 4.0]) * 10)
    nodes[:, 2] = 3000.0
    n = len(nodes)
    # a bow-tie nearly edge-on: corners 2 and 3 of a square swapped, tilted 89° about x
    c, s = np.cos(np.radians(89)), np.sin(np.radians(89))
    sq = np.array([[-1, -1, 0], [1, -1, 0], [-1, 1, 0], [1, 1, 0]], float) * 5
    sq = sq @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T + [0, 0, 3000.0]
    nodes = np.vstack([nodes, sq])
    quads = np.vstack([quads, [[n, n + 1, n + 2, n + 3]]])
    _, msgs = render_warnings(nodes, quads)
    labels = lambda m: m.split("elements ")[1].split(" are")[0].split(" have")[0]  # noqa: E731
    tiny = [m for m in msgs if "tiny" in m]
    assert len(tiny) == 1 and labels(tiny[0]) == "2, 6"
    bow = [m for m in msgs if str(len(quads)) in labels(m).split(", ")]
    assert len(bow) == 1 and "folded" in bow[0], msgs


BACKENDS = ["cpu", pytest.param("gl", marks=pytest.mark.gl)]


@pytest.mark.parametrize("mode", ["exact", "q4", "fast"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_pixels_mapping_outside_the_reference_are_counted(backend, mode, request):
    """The reference image cropped to its left part: every pixel whose reference point (from
    the render with the full image) lies beyond the crop is dropped, and the warning says
    how many — exactly, since each pixel centre belongs to one element."""
    import dataclasses

    from glsim.imaging.reference import Reference

    ctx = request.getfixturevalue("gl_ctx") if backend == "gl" else None
    nodes, quads = grid_mesh(np.linspace(-10, 10, 6), np.linspace(-7, 7, 5))
    nodes[:, 2] = 500.0
    scene, mesh = custom(nodes, quads, CAM)
    with Renderer(scene, backend, ctx=ctx, mesh=mesh) as r:
        full = r.render(0, 0, truth=True, mode=mode).truth
        ref = r.reference
    w = ref.image.shape[1] // 2
    cropped = Reference(np.ascontiguousarray(ref.image[:, :w]), dataclasses.replace(ref.camera, size=(w, ref.camera.size[1])), ref.dots)
    expected = int((full.mask & (full.ref_uv[..., 0] > w - 0.5)).sum())
    assert expected > 100
    with warnings.catch_warnings(record=True) as rec, Renderer(scene, backend, ctx=ctx, mesh=mesh,
                                                               reference=cropped) as r:
        warnings.simplefilter("always", RenderWarning)
        # GL: the same view three times, each warning with its own count
        truths = [r.render(0, 0, truth=True, mode=mode).truth for _ in range(3 if backend == "gl" else 1)]
    msgs = [str(x.message) for x in rec if "outside the reference image" in str(x.message)]
    assert len(msgs) == len(truths) and all(f": {expected} pixels" in m for m in msgs), (expected, msgs)
    for t in truths:
        assert t.mask.sum() == full.mask.sum() - expected
