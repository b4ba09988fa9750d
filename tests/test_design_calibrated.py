"""glsim design with a calibrated rig (``[calibration] rig = "targets"``): the stereo engine gets
the cameras calibrated from a simulated target library of the set-up's rig, not the scene's own,
so the calibration's error reaches the measured coordinates; the report and results.json carry
the calibration's errors against the truth."""
import json

import numpy as np
import pytest

from glsim.io.calibfiles import pyvale_calibration
from glsim.io.cameras import camera_from_dict
from glsim.scene import scene_from_dict
from glsim.workflows.design.cli import main

from _design import StandIn, stereo_plate, write_spec

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

TARGETS = {"rig": "targets", "pairs": 6, "seed": 1, "backend": "gl", "noise": 1.0}


@pytest.mark.gl
@pytest.mark.slow   # glsim design end to end, with a target library rendered and calibrated
def test_the_engine_measures_with_the_calibrated_cameras_and_the_report_gives_their_errors(tmp_path, monkeypatch, gl_ctx):
    import glsim.workflows.design.cli as cli
    scene_dict = stereo_plate(size=(320, 256), sigma=1.0, bit_depth=8)
    scene = scene_from_dict(scene_dict, ".")
    eng = StandIn(scene, 1)
    monkeypatch.setattr(cli, "make_engine", lambda name: eng)
    spec = write_spec(tmp_path / "spec.toml", scene_dict, engine="pyvale3d", dic={"subset_size": [21], "subset_step": 16},
                      realisations={"noise_seeds": [1]}, calibration=TARGETS, rank={"by": "p95_abs_W_mm"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "spec.toml"]     # the library inside -o
    done = [p for p in (out / "calibration").glob("calibration-*/result.json")]
    assert len(done) == 1
    stored = json.loads(done[0].read_text())
    est = [camera_from_dict(c) for c in stored["cameras"]]
    exchange, manifest = eng.seen[0]
    handed = json.loads((exchange / manifest["calibration"]).read_text())
    # what the engine got is the calibration's estimate, written out by glsim's own pyvale convention …
    assert handed == json.loads(json.dumps(pyvale_calibration(*est)))
    # … which is not the scene's exact rig (a calibration from noisy target images errs) …
    exact = json.loads(json.dumps(pyvale_calibration(scene.camera("cam0"), scene.camera("cam1"))))
    assert handed != exact
    # … and its report's errors are the estimate − truth of the cameras handed over, recomputed
    # here from the scene (fx, cx of both cameras; the stereo translation from camera poses, written out)
    rep = stored["report"]
    print(f"calibration: RMS {rep['rms_px']:.4f} px, |ΔT| {rep['T_norm_mm']:.4f} mm, "
          f"rotation {rep['rotation_deg']:.5f}°, {rep['seconds']:.1f} s")
    truth = [scene.camera("cam0"), scene.camera("cam1")]
    for i in (0, 1):
        assert rep["errors"][f"fx{i + 1}"] == pytest.approx(est[i].fx - truth[i].fx, abs=1e-9)
        assert rep["errors"][f"cx{i + 1}"] == pytest.approx(est[i].cx - truth[i].cx, abs=1e-9)

    def stereo_t(c0, c1):       # camera 1's position of camera 0's origin: t1 − R1·R0ᵀ·t0
        R0, R1 = np.asarray(c0.rotation), np.asarray(c1.rotation)
        return np.asarray(c1.translation) - R1 @ R0.T @ np.asarray(c0.translation)
    assert rep["T_norm_mm"] == pytest.approx(np.linalg.norm(stereo_t(*est) - stereo_t(*truth)), abs=1e-9)
    assert 0 < rep["rms_px"] < 0.05 and rep["pairs_used"] == 6
    res = json.loads((out / "results.json").read_text())
    assert res["calibration"]["rig"] == "targets"
    assert res["calibration"]["setups"]["v0000"]["T_norm_mm"] == rep["T_norm_mm"]
    assert 'id="calibration"' in (out / "report.html").read_text()
    # resumed: the calibration is read back, no row measured again
    calls = eng.calls
    assert main([str(spec), "-o", str(out), "-q"]) == 0 and eng.calls == calls


def test_a_calibrated_rig_without_a_stereo_engine_is_refused_by_key(tmp_path, capsys):
    from _design import plate_scene
    spec = write_spec(tmp_path / "spec.toml", plate_scene(size=(256, 256)), engine="pyvale2d",
                      dic={"subset_size": [21]}, calibration=TARGETS)
    assert main([str(spec), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "calibration.rig: 'targets' calibrates a stereo rig" in err[0] and "pyvale3d" in err[0]
    assert not (tmp_path / "out").exists()
