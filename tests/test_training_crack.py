"""A crack made by [specimen.field] (the mesh split along it) seen through the labels: the pixels
on the crack are masked, the rest of the image is valid, and the backward flow jumps across the
crack by the opening the field prescribes — worked out here from the field's definition
(opening · √(r/a) at distance r from the interior tip of a crack of length a), not from glsim."""
import math

import numpy as np
import pytest

from glsim.render import Renderer
from glsim.scene import scene_from_dict
from glsim.workflows.training.labels import pair_labels

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

OPENING_MM, LENGTH_MM, MM_PER_PX = 0.05, 14.0, 0.1   # fx = 3000 px at 300 mm


def _scene(backend):
    """A 28 × 28 mm plate filling a 256² camera square on (0.1 mm per px); a crack from the plate's
    left edge (x = −14 mm) to its centre along y = 0, opening 0.05 mm (0.5 px) in +y."""
    return scene_from_dict({
        "cameras": [{"name": "cam0", "size": [256, 256], "fx": 3000.0, "fy": 3000.0, "cx": 127.5, "cy": 127.5,
                     "bit_depth": 8}],
        "specimen": {"plate": {"width": 28.0, "height": 28.0, "nx": 28, "ny": 28}, "pose": {"t": [0.0, 0.0, 300.0]},
                     "field": {"seed": 1, "cracks": [{"start": [-LENGTH_MM, 0.0], "end": [0.0, 0.0],
                                                      "opening": [0.0, OPENING_MM, 0.0]}]}},
        "speckle": {"dot_diameter_px": 4.0, "seed": 0}, "render": {"backend": backend, "mode": "exact"}}, ".")


@pytest.mark.gl
def test_a_field_crack_is_masked_and_its_labels_jump_by_the_opening(gl_ctx):
    scene = _scene("gl")
    with Renderer(scene, ctx=gl_ctx) as r:
        ref, dfm = r.render("cam0", step=0, truth=True), r.render("cam0", step=1, truth=True)
    labels = pair_labels(scene, 1, {"cam0": ref.truth}, {"cam0": dfm.truth})
    mask, flow = labels["mask_flow0"], labels["flow0"]
    # the crack runs between rows 127 and 128 (y = 0 mm) over columns 0 … 127 (x < 0)
    far = np.ones(mask.shape, bool)
    far[124:132, :] = False
    assert mask[far].all()                                   # away from the crack every label is valid
    # masked along the whole crack, to its tip at column 127.5: near the tip the opening (0.12 px at
    # column 120) is below the jump rule's threshold, and the split of the mesh marks it
    assert not mask[127:129, 0:127].any()
    for col in (10, 40, 80):                                 # where the opening is ≥ 0.3 px
        x_mm = (col - 127.5) * MM_PER_PX
        jump_px = OPENING_MM * math.sqrt(-x_mm / LENGTH_MM) / MM_PER_PX
        above, below = flow[124, col, 1], flow[131, col, 1]
        # the side left of start → end (+y: image rows below) moved by the opening, the other not;
        # 3.5 px from the crack the profile's Gaussian decay exp(−d²/2a²) is 1 − 1e-4 (a = 14 mm)
        assert above == pytest.approx(0.0, abs=1e-6)
        assert below == pytest.approx(-jump_px, abs=1e-3), col
        assert np.all(np.abs(flow[124:132, col, 0]) < 1e-6)  # no motion along the crack
    # the right half (x > 0) is beyond the tip: not split, not masked, not moved
    assert mask[120:136, 140:250].all() and np.abs(flow[:, 140:250]).max() < 1e-6
