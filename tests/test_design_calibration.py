"""The design planner's [calibration] table and the rig it measures with (glsim.workflows.design.calibration):
refusals by key, the exact rig, and a stereo calibration from a simulated target library of the
Table 8 rig at 406 × 308 px checked against the truth."""
import contextlib
import math
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from glsim.errors import SceneError
from glsim.io.calibfiles import pyvale_calibration, read_rig_yaml, stereo_extrinsics
from glsim.scene import Noise, Render, Scene
from glsim.scene.camera import Camera, rotation_xyz
from glsim.workflows.calib import library as libmod
from glsim.workflows.design import calibration as dc
from glsim.workflows.library.spec import SpecError

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

CI_SCALE = 0.25


def _scene(cams=None, backend="gl") -> Scene:
    return Scene(cameras=cams or libmod.paper_rig(CI_SCALE), render=Render(backend=backend, mode="exact"))


def _files(root: Path) -> set:
    return {p.relative_to(root) for p in root.rglob("*")}


# --- the table ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("table, key, culprit, fix", [
    ({"rig": "target"}, "calibration.rig", "'target'", "did you mean 'targets'"),
    ({"rig": 1}, "calibration.rig", "1", "rig = \"exact\""),
    ({"pair": 10, "rig": "targets"}, "calibration.pair", "unknown key", "did you mean 'pairs'"),
    ({"rig": "exact", "pairs": 10}, "calibration.pairs", "rig is \"exact\"", "rig = \"targets\""),
    ({"rig": "targets", "pairs": 2}, "calibration.pairs", "got 2", "at least 3"),
    ({"rig": "targets", "pairs": 7.5}, "calibration.pairs", "got 7.5", "pairs = 15"),
    ({"rig": "targets", "pairs": True}, "calibration.pairs", "got True", "pairs = 15"),
    ({"rig": "targets", "target": "dot"}, "calibration.target", "'dot'", "did you mean 'dots'"),
    ({"rig": "targets", "pitch_mm": 0}, "calibration.pitch_mm", "got 0", "pitch_mm = \"auto\""),
    ({"rig": "targets", "pitch_mm": "big"}, "calibration.pitch_mm", "got 'big'", "pitch_mm = \"auto\""),
    ({"rig": "targets", "noise": -1}, "calibration.noise", "got -1", "noise = 2"),
    ({"rig": "targets", "noise": "2"}, "calibration.noise", "got '2'", "noise = 2"),
    ({"rig": "targets", "noise": math.nan}, "calibration.noise", "got nan", "noise = 2"),
    ({"rig": "targets", "fov": "edge"}, "calibration.fov", "'edge'", "fov = \"full\""),
    ({"rig": "targets", "model": "k1k2k3"}, "calibration.model", "'k1k2k3'", "did you mean"),
    ({"rig": "targets", "seed": -1}, "calibration.seed", "got -1", "seed = 0"),
    ({"rig": "targets", "seed": 2 ** 32}, "calibration.seed", f"got {2 ** 32}", "seed = 0"),
    ({"rig": "targets", "backend": "vulkan"}, "calibration.backend", "'vulkan'", "backend = \"gl\""),
])
def test_bad_keys_are_refused_by_name(table, key, culprit, fix):
    with pytest.raises(SpecError) as e:
        dc.calibration_spec(table)
    text = str(e.value)
    assert text.startswith(f"{key}: ") and culprit in text and " — " in text and fix in text.split(" — ", 1)[1]


def test_a_non_table_and_a_prefix():
    with pytest.raises(SpecError, match=r"^calibration: expected a table, got 'targets'"):
        dc.calibration_spec("targets")
    with pytest.raises(SpecError, match=r"^design\.calibration\.pairs: "):
        dc.calibration_spec({"rig": "targets", "pairs": 0}, key_prefix="design.calibration")


def test_defaults_and_values_read():
    assert dc.calibration_spec({}) == dc.calibration_spec({"rig": "exact"}) == dc.CalibrationSpec()
    s = dc.calibration_spec({"rig": "targets"})
    assert (s.rig, s.pairs, s.target, s.pitch_mm, s.noise, s.fov, s.model, s.seed, s.backend) == \
        ("targets", 15, "dots", None, None, "full", "k1k2p1p2k3", 0, None)
    s = dc.calibration_spec({"rig": "targets", "pairs": 8, "target": "charuco", "pitch_mm": 12, "noise": 0,
                             "fov": "centre", "model": "k1k2", "seed": 9, "backend": "cpu"})
    assert (s.pairs, s.target, s.pitch_mm, s.noise, s.fov, s.model, s.seed, s.backend) == \
        (8, "charuco", 12.0, 0.0, "centre", "k1k2", 9, "cpu")


# --- the exact rig, the target and the refusals of a scene ------------------------------------------------

def test_exact_rig_is_the_scene_cameras_with_zero_error(tmp_path):
    scene = _scene()
    r = dc.calibrated_rig(dc.calibration_spec({"rig": "exact"}), scene, tmp_path / "work")
    assert r.rig == "exact" and r.cam0 is scene.cameras[0] and r.cam1 is scene.cameras[1]
    assert r.report["rms_px"] == 0 and r.report["T_norm_mm"] == 0 and r.report["rotation_deg"] == 0
    assert set(r.report["errors"].values()) == {0.0}
    assert not (tmp_path / "work").exists()


def test_targets_need_two_converging_cameras(tmp_path):
    spec = dc.calibration_spec({"rig": "targets"})
    one = _scene(libmod.paper_rig(CI_SCALE)[:1])
    with pytest.raises(SpecError, match=r"^calibration\.rig: .*has 1 camera — give the scene two cameras"):
        dc.calibrated_rig(spec, one, tmp_path)
    a = libmod.paper_rig(CI_SCALE)[0]
    b = Camera(name="cam1", size=a.size, fx=a.fx, fy=a.fy, cx=a.cx, cy=a.cy, t=(-100.0, 0.0, 0.0))
    with pytest.raises(SpecError, match=r"^calibration\.rig: cameras cam0 and cam1 look in parallel"):
        dc.calibrated_rig(spec, _scene((a, b)), tmp_path)
    # turned 24° away from camera 0 instead of towards it: the axes meet behind the cameras
    R = rotation_xyz(0.0, -24.0, 0.0)
    away = Camera(name="cam1", size=a.size, fx=a.fx, fy=a.fy, cx=a.cx, cy=a.cy, R=R, t=-R @ [122.0, 0.0, 26.0])
    with pytest.raises(SpecError, match=r"^calibration\.rig: cameras cam0 and cam1 see nothing in common"):
        dc.calibrated_rig(spec, _scene((a, away)), tmp_path)
    with pytest.raises(SpecError, match=r"^calibration\.rig: cameras cam0 and cam1 see nothing in common"):
        dc.auto_pitch((a, away), "dots")
    assert not any(tmp_path.iterdir())


def test_noise_is_the_spec_s_else_the_scene_s_else_two_percent():
    plain, own = _scene(), _scene().replace(noise={"sigma": 0.7})
    spec = dc.calibration_spec({"rig": "targets"})
    assert dc.resolved_noise(spec, plain) == Noise(sigma=2.0) and dc.resolved_noise(spec, own) == Noise(sigma=0.7)
    assert dc.resolved_noise(dc.calibration_spec({"rig": "targets", "noise": 1.5}), own) == Noise(sigma=1.5)
    assert dc.resolved_noise(dc.calibration_spec({"rig": "targets", "noise": 0}), own) is None
    assert dc.inputs_hash(spec, plain) != dc.inputs_hash(spec, own)      # another sensor, another calibration


def test_auto_pitch_follows_the_field_of_view():
    """The Table 8 rig gets the library's 10 mm target; the same rig shrunk ten times about its
    first camera (same images, a field of view ten times smaller) a 1 mm one."""
    cams = libmod.paper_rig(CI_SCALE)
    assert dc.auto_pitch(cams, "dots") == 10.0
    small = tuple(Camera(**{**{f: getattr(c, f) for f in ("name", "size", "fx", "fy", "cx", "cy", "distortion",
                                                              "R", "bit_depth")}, "t": np.array(c.t) / 10})
                  for c in cams)
    assert dc.auto_pitch(small, "dots") == 1.0
    assert [dc.nice(x) for x in (0.98, 1.05, 1.1, 1.4, 2.7, 7.2, 9.82, 130.0, 0.13)] == \
        [1.0, 1.0, 1.2, 1.5, 2.5, 8.0, 10.0, 120.0, 0.12]
    t = dc.make_target("dots", 1.0, 100.0)
    assert (t.pitch, t.dot_diameter, t.marker_diameter, t.margin) == (1.0, 0.5, 0.3, 1.0)


# --- a calibration from a rendered library (GL) ---------------------------------------------------------

# Bounds: five standard deviations of the reduced study's calibrations of this very set-up
# (bench/results/calib_study/summary_images.md: the Table 8 rig at 406 × 308 px, 2 % noise, full
# field of view, 10 pairs, 30 runs): std fx1 0.15 px, cx1 0.11 px, k1 0.0016 (camera 0) / 0.0010
# (camera 1), Tz 0.073 mm, Phi 0.011°, mean RMS 0.011 px. fy, cy and camera 1 take camera 0's fx, cx
# spreads (same optics to 7 %); |ΔT| and the rotation angle take √3 × the Tz and Phi spreads (three
# components, none spread wider than these in the study's runs). A single Gaussian draw passes
# 5 σ with probability 1 − 6e-7 per parameter. The RMS is the detection noise, not a draw of the
# poses (0.011 px at every study size): twice the study's mean.
PAIRS, SEED = 10, 3
BOUND = {"fx": 5 * 0.15, "fy": 5 * 0.15, "cx": 5 * 0.11, "cy": 5 * 0.11}
BOUND_K1 = {1: 5 * 0.0016, 2: 5 * 0.0010}
BOUND_T_MM, BOUND_ROT_DEG, BOUND_RMS_PX = 5 * 0.073 * math.sqrt(3), 5 * 0.011 * math.sqrt(3), 2 * 0.011


SPEC = {"rig": "targets", "pairs": PAIRS, "seed": SEED}


def _make(gl_ctx):
    """``make(d)`` for shared_dir: dc.calibrated_rig of SPEC made anew in d/work with d the
    working directory; d/made.pickle: the rig it returned and what it wrote in d (only work)."""
    def make(d):
        d.mkdir()
        with contextlib.chdir(d):
            rig = dc.calibrated_rig(dc.calibration_spec(SPEC), _scene(), d / "work", ctx=gl_ctx)
        (d / "made.pickle").write_bytes(pickle.dumps((rig, sorted(p.name for p in d.iterdir()))))
    return make


def _copy(built: Path, work: Path):
    """This worker's copy of a made calibration's work directory at ``work`` (mtimes kept) and
    what was made."""
    shutil.copytree(built / "work", work)
    return pickle.loads((built / "made.pickle").read_bytes())


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory, gl_ctx, shared_dir):
    """The calibration of SPEC, made once per run for every worker: its work directory (each
    worker's own copy) and the rig calibrated_rig returned when it made it. A worker that finds
    another making it makes test_same_seed_same_numbers_reused_and_resumed's second one meanwhile."""
    if shared_dir("design-calibration", _make(gl_ctx), wait=False) is None:
        shared_dir("design-calibration-anew", _make(gl_ctx), wait=False)
    root = tmp_path_factory.mktemp("design_calibration")
    rig, _ = _copy(shared_dir("design-calibration", _make(gl_ctx)), root / "work")
    return root, dc.calibration_spec(SPEC), rig


@pytest.fixture
def made_anew(gl_ctx, shared_dir, tmp_path):
    """A second calibration of SPEC, made anew from nothing (in another directory, by another
    process or this one): the copy of its work directory in tmp_path/w2, the rig calibrated_rig
    returned, and the names it wrote in its working directory."""
    return _copy(shared_dir("design-calibration-anew", _make(gl_ctx)), tmp_path / "w2")


@pytest.mark.gl
@pytest.mark.slow   # a whole target library rendered and calibrated
def test_targets_calibration_is_near_the_truth(calibrated):
    root, _, r = calibrated
    true0, true1 = libmod.paper_rig(CI_SCALE)
    assert r.rig == "targets" and r.report["pairs_used"] >= PAIRS and r.report["pitch_mm"] == 10.0
    assert r.report["noise"]["sigma"] == 2.0                        # the scene has no [noise]: Table 8's 2 %
    for i, (est, true) in enumerate(((r.cam0, true0), (r.cam1, true1)), 1):
        for p, bound in BOUND.items():
            err = getattr(est, p) - getattr(true, p)
            assert abs(err) < bound, (est.name, p, err)
            assert r.report["errors"][f"{p}{i}"] == pytest.approx(err, abs=1e-9)
        err_k1 = est.distortion.k1 - true.distortion.k1
        assert abs(err_k1) < BOUND_K1[i] and r.report["errors"][f"k1_{i}"] == pytest.approx(err_k1, abs=1e-12)
        assert (est.name, est.size, est.bit_depth) == (true.name, true.size, true.bit_depth)
    # camera 0 keeps the scene's world pose; the pair's extrinsics are the calibration's (its YAML)
    assert np.allclose(r.cam0.rotation, true0.rotation) and np.allclose(r.cam0.translation, true0.translation)
    R, T = stereo_extrinsics(r.cam0, r.cam1)
    R_true, T_true = stereo_extrinsics(true0, true1)
    dT = float(np.linalg.norm(T - T_true))
    angle = math.degrees(math.acos(min(1.0, (np.trace(R @ R_true.T) - 1) / 2)))
    assert 0 < dT < BOUND_T_MM and 0 < angle < BOUND_ROT_DEG              # a calibration, not the truth
    assert r.report["T_norm_mm"] == pytest.approx(dT, abs=1e-9)
    assert r.report["rotation_deg"] == pytest.approx(angle, abs=1e-6)
    assert r.report["rms_px"] < BOUND_RMS_PX
    (yaml,) = (root / "work").glob("calibration-*/calibration/calibration.yaml")
    y = read_rig_yaml(yaml)
    assert np.allclose(y["K1"], r.cam0.K, rtol=1e-12) and np.allclose(y["K2"], r.cam1.K, rtol=1e-12)
    assert np.allclose(y["R"], R, atol=1e-12) and np.allclose(y["T"], T, atol=1e-9)
    assert np.allclose(pyvale_calibration(r.cam0, r.cam1)["translation"], y["T"], atol=1e-9)


@pytest.mark.gl
@pytest.mark.slow   # a whole target library rendered and calibrated
def test_same_seed_same_numbers_reused_and_resumed(calibrated, made_anew, gl_ctx, tmp_path, monkeypatch):
    root, spec, r = calibrated
    monkeypatch.chdir(tmp_path)
    before = _files(root)
    again = dc.calibrated_rig(spec, _scene(), root / "work", ctx=gl_ctx)          # a finished one: read back
    assert again == r and _files(root) == before
    other, wrote = made_anew                                                      # made anew: the same numbers
    assert (other.cam0, other.cam1) == (r.cam0, r.cam1) and other.report["errors"] == r.report["errors"]
    assert wrote == ["work"]                                                      # nothing outside the workdir
    (d,) = (tmp_path / "w2").glob("calibration-*")
    (d / "result.json").unlink()                                                  # interrupted before the end
    pairs = sorted(p.name for p in (d / "library" / "pairs").iterdir())
    stamps = {p: p.stat().st_mtime_ns for p in (d / "library" / "pairs").iterdir()}
    resumed = dc.calibrated_rig(spec, _scene(), tmp_path / "w2", ctx=gl_ctx)
    assert (resumed.cam0, resumed.cam1) == (r.cam0, r.cam1)
    assert {p: p.stat().st_mtime_ns for p in (d / "library" / "pairs").iterdir()} == stamps   # not rendered again
    assert sorted(p.name for p in (d / "library" / "pairs").iterdir()) == pairs
    assert {p.parts[0] for p in _files(tmp_path)} == {"w2"}                       # nothing outside the workdir
    (d / "result.json").write_text("{")
    with pytest.raises(SceneError, match="result.json: is not a finished calibration .* — delete"):
        dc.calibrated_rig(spec, _scene(), tmp_path / "w2", ctx=gl_ctx)


@pytest.mark.gl
@pytest.mark.slow   # a whole target library rendered and calibrated
def test_another_seed_another_calibration(calibrated, gl_ctx, tmp_path):
    _, _, r = calibrated
    other = dc.calibrated_rig(dc.calibration_spec({"rig": "targets", "pairs": 3, "seed": SEED + 1}), _scene(),
                              tmp_path, ctx=gl_ctx)
    assert other.cam0.fx != r.cam0.fx and len(list(tmp_path.glob("calibration-*"))) == 1
