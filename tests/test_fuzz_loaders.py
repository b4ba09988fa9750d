"""A property-based fuzz of the scene and library-spec loaders (hostile inputs, issue 30): random
structure, types and sizes in any table must raise nothing but glsim's own errors."""
import copy
import dataclasses
import warnings

import pytest

from glsim.errors import GlsimError
from glsim.scene import model, optional, scene_from_dict, tables
from glsim.scene.camera import Camera, Distortion
from glsim.workflows.library import expand
from glsim.workflows.library.spec import TOP_KEYS

hypothesis = pytest.importorskip("hypothesis")
st = hypothesis.strategies

_NAMES = set(tables.SECTIONS) | set(TOP_KEYS)
for _cls in (Camera, Distortion, model.Speckle, model.Plate, model.Bulge, model.MeshFile, model.Specimen,
             model.Render, model.Output, optional.Light, optional.Lighting, optional.Optics, optional.Noise,
             optional.Sensor, optional.Psf, optional.Vignetting, optional.Exposure, tables.Stereo, tables.LookAt,
             tables.Pose):
    _NAMES |= {f.name for f in dataclasses.fields(_cls)}
KEYS = st.sampled_from(sorted(_NAMES)) | st.text(max_size=4)
LEAVES = (st.none() | st.booleans() | st.integers(-2 ** 70, 2 ** 70) | st.floats() | st.text(max_size=6)
          | st.sampled_from(["gl", "cpu", "exact", "grid", "zip", "random", "x.inp", "0-3", "{camera}_{step}.{ext}"]))
VALUES = st.recursive(LEAVES, lambda c: st.lists(c, max_size=4) | st.dictionaries(KEYS, c, max_size=5), max_leaves=25)
BASE = {"cameras": [{"size": [64, 48], "fx": 300.0, "fy": 300.0, "cx": 31.5, "cy": 23.5},
                    {"size": [64, 48], "fx": 300.0, "fy": 300.0, "cx": 31.5, "cy": 23.5,
                     "pose": {"stereo": {"Tx": -50.0, "Ty": 0.0, "Tz": 0.0, "Theta": 0.0, "Phi": 10.0, "Psi": 0.0}}}],
        "specimen": {"plate": {"translations": [[0.1, 0.0, 0.0]]}, "pose": {"t": [0.0, 0.0, 300.0]}},
        "speckle": {"dot_diameter_px": 4.0}, "render": {"backend": "cpu", "samples_per_pixel": 4},
        "noise": {"sigma": 1.0}, "lighting": {"lights": [{"position": [0.0, 0.0, 0.0]}]},
        "optics": {"focal_length": 50.0, "f_number": 8.0, "focus_distance": 300.0, "pixel_pitch": 0.005}}


def _paths(d, prefix=()):
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    return [prefix] + [p for k, v in items for p in _paths(v, prefix + (k,))]


@st.composite
def scenes(draw):
    """The base scene with 1–3 values replaced (or keys added) by random nested data."""
    d = copy.deepcopy(BASE)
    for _ in range(draw(st.integers(1, 3))):
        *parents, last = draw(st.sampled_from(_paths(BASE)[1:]))
        table = d
        try:
            for k in parents:
                table = table[k]
            table[draw(KEYS) if isinstance(table, dict) and draw(st.booleans()) else last] = draw(VALUES)
        except (KeyError, IndexError, TypeError):
            pass                    # an earlier replacement removed the path
    return d


def only_glsim_errors(fn, *args) -> None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fn(*args)
    except GlsimError:
        pass


@hypothesis.settings(max_examples=150, deadline=None, suppress_health_check=list(hypothesis.HealthCheck))
@hypothesis.given(st.one_of(scenes(), st.dictionaries(KEYS, VALUES, max_size=6)))
def test_fuzz_the_scene_loader_raises_only_glsim_errors(tmp_path_factory, data):
    only_glsim_errors(scene_from_dict, data, str(tmp_path_factory.getbasetemp()))


@hypothesis.settings(max_examples=150, deadline=None, suppress_health_check=list(hypothesis.HealthCheck))
@hypothesis.given(st.dictionaries(st.sampled_from(TOP_KEYS) | KEYS, VALUES, max_size=6), scenes())
def test_fuzz_the_spec_loader_raises_only_glsim_errors(tmp_path_factory, spec_table, base):
    only_glsim_errors(expand, {"scene": base, **spec_table}, str(tmp_path_factory.getbasetemp()))
