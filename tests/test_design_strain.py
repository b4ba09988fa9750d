"""glsim design's strain without an engine: the [dic] strain keys refused by key before anything is
written, a strain-free spec unchanged (setting names, row keys, manifest), the truth's strain
measures against scipy's matrix functions on an imposed affine field, and the strain maps and
criteria of a run with a stand-in 2-D engine that answers the exact strain plus known errors."""
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla
import tifffile

from glsim.io.fe import specimen_mesh
from glsim.scene import scene_from_dict
from glsim.workflows.design import planar, quick, run as runmod, strain
from glsim.workflows.design.cli import main
from glsim.workflows.design.engine import Pyvale2D, SubsetResults, write_exchange
from glsim.workflows.design.spec import DicSetting, check_design, row_key

import _design
from _design import plate_scene, stereo_plate, write_spec

G = [[0.01, 0.004], [-0.002, -0.005]]     # ∂(u, v)/∂(X, Y): the plate's imposed affine field
BIAS, SPREAD = 2e-4, 1e-4                 # the stand-in's strain bias and per-realisation offset


def strained_plate(gradient=G, size=(256, 256)) -> dict:
    """The design tests' plate square onto the camera, the affine field u = G·(X − centre) at step 1."""
    sc = plate_scene(size, (0.0, 0.0), 1.0, 8)
    sc["specimen"]["field"] = {"affine": {"gradient": gradient}}
    return sc


def reference_strain(F: np.ndarray, formulation: str) -> np.ndarray:
    """pyvale's measures written with scipy's matrix functions (independent of glsim's eigh)."""
    C, B = F.T @ F, F @ F.T
    return {"GREEN": 0.5 * (C - np.eye(2)), "ALMANSI": 0.5 * (np.eye(2) - np.linalg.inv(B)),
            "HENCKY": 0.5 * np.real(sla.logm(C)), "BIOT_LAGRANGE": np.real(sla.sqrtm(C)) - np.eye(2),
            "BIOT_EULER": np.real(sla.sqrtm(B)) - np.eye(2)}[formulation]


# ---- refusals --------------------------------------------------------------------------------------
BAD = [({"subset_size": [21], "strain_window": [4]}, "pyvale2d", "dic.strain_window: 4 is not allowed"),
       ({"subset_size": [21], "strain_window": 1}, "pyvale2d", "dic.strain_window: 1 is not allowed"),
       ({"subset_size": [21], "strain_window": [5, 5]}, "pyvale2d", "dic.strain_window: [5, 5] repeats"),
       ({"subset_size": [21], "strain_window": 5, "strain_element": 8}, "pyvale2d", "dic.strain_element: 8"),
       ({"subset_size": [21], "strain_window": 5, "strain_formulation": "green"}, "pyvale2d",
        "dic.strain_formulation: 'green' is not allowed"),
       ({"subset_size": [21], "strain_formulation": "GREEN"}, "pyvale2d",
        "dic.strain_formulation: sets pyvale's strain, and dic.strain_window is not given"),
       ({"subset_size": [21], "strain_window": 5}, "quick", "dic.strain_window: strain is computed by a measuring engine"),
       ({"subset_size": [21], "strain_windows": 5}, "pyvale2d", "dic.strain_windows: unknown key")]


@pytest.mark.parametrize("dic,engine,key", BAD)
def test_bad_strain_keys_are_refused_by_key_before_anything_is_written(tmp_path, capsys, dic, engine, key):
    spec = write_spec(tmp_path / "spec.toml", strained_plate(), engine=engine, dic=dic)
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err and " — " in err
    assert not out.exists()


def test_ranking_by_strain_needs_strain(tmp_path, capsys):
    for engine, scene in (("pyvale2d", strained_plate()), ("pyvale3d", stereo_plate())):
        spec = write_spec(tmp_path / f"{engine}.toml", scene, engine=engine, dic={"subset_size": [21]},
                          rank={"by": "strain_noise_floor"})
        assert main([str(spec), "-o", str(tmp_path / "out")]) == 2
        assert "rank.by: 'strain_noise_floor' ranks by strain, and [dic] asks for none" in capsys.readouterr().err
        assert not (tmp_path / "out").exists()


def test_strain_settings_are_every_combination_with_the_other_dic_keys(tmp_path):
    d = check_design({"engine": "pyvale2d", "scene": strained_plate(),
                      "dic": {"subset_size": [21, 31], "strain_window": [5, 9], "strain_formulation": ["GREEN", "HENCKY"]}},
                     tmp_path)
    assert len(d.settings) == 8 and len({s.name for s in d.settings}) == 8
    assert DicSetting(21, 10, "affine", 5, 9, "GREEN") in d.settings
    assert all(s.strain_element == 9 for s in d.settings)     # pyvale's default element
    assert d.settings[0].strain == {"window_size": 5, "window_element": 9, "strain_formulation": "GREEN"}


# ---- without strain keys nothing changes ----------------------------------------------------------------
def test_without_strain_keys_names_row_keys_and_manifest_are_as_before(tmp_path):
    spec = {"engine": "pyvale2d", "scene": strained_plate(), "dic": {"subset_size": [21, 31]},
            "realisations": {"noise_seeds": [1]}}
    d = check_design(spec, tmp_path)
    assert [s.name for s in d.settings] == ["s21-st10-affine", "s31-st10-affine"]
    assert all(s.strain is None and s.strain_window is None for s in d.settings)
    # the row key's payload is the one of before strain: no strain field anywhere in it
    scene = d.plan.variants[0].scene
    base = {"format": runmod.FORMAT, "version": runmod.ROW_VERSION, "scene": json.loads(scene.to_json()),
            "camera": d.camera, "step": d.step, "roi_margin": d.roi_margin}
    want = [row_key({**base, "setting": s, "kind": k, "noise_seed": n})
            for s in ("s21-st10-affine", "s31-st10-affine") for k, n in (("quick", None), ("pyvale2d", 1))]
    assert [r.key for r in runmod.rows(d, "pyvale2d")] == want
    # with strain the keys are others' (a strain row is not a cached strain-free one)
    d2 = check_design({**spec, "dic": {"subset_size": [21, 31], "strain_window": 5}}, tmp_path)
    assert not {r.key for r in runmod.rows(d2, "pyvale2d")} & set(want)
    # the exchange's manifest holds no strain table, as glsim verify sweep's
    roi = np.zeros((64, 64), bool)
    roi[8:56, 8:56] = True
    img = np.zeros((64, 64))
    write_exchange(tmp_path / "x", img, [img], roi, 21, 10, "affine", 16)
    assert "strain" not in json.loads((tmp_path / "x" / "manifest.json").read_text())
    write_exchange(tmp_path / "y", img, [img], roi, 21, 10, "affine", 16, strain=d2.settings[0].strain)
    assert json.loads((tmp_path / "y" / "manifest.json").read_text())["strain"] == {
        "window_size": 5, "window_element": 9, "strain_formulation": "HENCKY"}


def test_engine_npz_without_strain_arrays_gives_no_strain(tmp_path):
    x = tmp_path / "exchange"
    x.mkdir()
    arrays = {"ss_x": np.arange(3.0), "ss_y": np.arange(3.0), "u": np.zeros((2, 3)), "v": np.zeros((2, 3)),
              "valid": np.ones((2, 3), bool), "cost": np.ones((2, 3)), "seconds": np.float64(1.0),
              "pyvale_version": np.str_("x")}
    np.savez(x / "measured_r_run.npz", **arrays)
    eng = Pyvale2D(python=Path("/bin/true"), script=Path(__file__))    # true: the npz is already there
    m = eng.measure(x)
    assert m.strain_x is None and m.exx is None
    np.savez(x / "measured_r_run.npz", **arrays, strain_x=np.arange(2.0), strain_y=np.arange(2.0),
             exx=np.zeros((2, 2)), eyy=np.zeros((2, 2)), exy=np.zeros((2, 2)), strain_valid=np.ones((2, 2), bool))
    m = eng.measure(x)
    assert m.exx.shape == (2, 2) and m.strain_valid.dtype == bool


# ---- the truth -------------------------------------------------------------------------------------
@pytest.mark.parametrize("formulation", ["GREEN", "ALMANSI", "HENCKY", "BIOT_EULER", "BIOT_LAGRANGE"])
def test_truth_strain_of_an_affine_field_is_pyvales_measure_of_I_plus_G(formulation):
    """A plate square onto the camera at constant depth: image px/px = plate mm/mm, so the image
    motion's gradient is the imposed G at every point; the truth is the measure of F = I + G."""
    scene = scene_from_dict(strained_plate(), ".")
    prep = planar.Prepared(scene, "cam0", 1, specimen_mesh(scene), None, np.zeros((256, 256)), None, None)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(40, 216, 50), rng.uniform(40, 216, 50)
    t = strain.truth(lambda a, b: planar._motion(prep, a, b), x, y, formulation)
    want = reference_strain(np.eye(2) + np.array(G), formulation)
    assert t["truth_strain_valid"].all()
    np.testing.assert_allclose(t["truth_exx"], want[0, 0], atol=1e-10)
    np.testing.assert_allclose(t["truth_eyy"], want[1, 1], atol=1e-10)
    np.testing.assert_allclose(t["truth_exy"], want[0, 1], atol=1e-10)
    # outside the plate: no truth
    out = strain.truth(lambda a, b: planar._motion(prep, a, b), np.array([2.0]), np.array([2.0]), formulation)
    assert not out["truth_strain_valid"][0] and math.isnan(out["truth_exx"][0])


# ---- the maps against a stand-in engine ---------------------------------------------------------------
@dataclasses.dataclass
class StandIn2D:
    """A 2-D engine that reads the exchange as verify/dic2d.py does and answers zero displacement
    and, at the subset centres as strain points, the strain of I + G (scipy, in the manifest's
    formulation) plus BIAS plus a per-realisation offset (−1, 0, +1)·SPREAD; the static pair the
    offset only. Every 5th strain point invalid in the deformed state."""
    name: str = "pyvale2d"
    calls: int = 0
    seen: list = dataclasses.field(default_factory=list)

    def missing(self):
        return None

    def measure(self, exchange: Path) -> SubsetResults:
        manifest = json.loads((exchange / "manifest.json").read_text())
        self.seen.append(manifest)
        roi = tifffile.imread(exchange / manifest["roi"]) > 0
        kw = manifest["calculate_2d"]
        c = quick.grid_centres(roi, manifest["runs"][0]["subset_size"], kw["subset_step"]).astype(float)
        n = len(c)
        off = (-1, 0, 1)[self.calls % 3] * SPREAD
        self.calls += 1
        eps = reference_strain(np.eye(2) + np.array(G), manifest["strain"]["strain_formulation"])
        comp = {k: np.stack([np.full(n, off), np.full(n, eps[i, j] + BIAS + off)])
                for k, (i, j) in (("exx", (0, 0)), ("eyy", (1, 1)), ("exy", (0, 1)))}
        sv = np.ones((2, n), bool)
        sv[1, ::5] = False
        z = np.zeros((2, n))
        return SubsetResults(c[:, 0], c[:, 1], z, z, np.ones((2, n), bool), np.ones((2, n)), 0.0, "stand-in",
                             strain_x=c[:, 0], strain_y=c[:, 1], strain_valid=sv, **comp)


@pytest.mark.slow   # glsim design end to end
def test_strain_maps_criteria_and_report_against_injected_errors(tmp_path, monkeypatch):
    import glsim.workflows.design.cli as cli
    eng = StandIn2D()
    monkeypatch.setattr(cli, "make_engine", lambda name: eng)
    spec = write_spec(tmp_path / "spec.toml", strained_plate(), engine="pyvale2d",
                      dic={"subset_size": [31], "subset_step": 16, "strain_window": [5, 7],
                           "strain_formulation": "GREEN"},
                      realisations={"noise_seeds": [1, 2, 3]}, rank={"by": "rms_strain_bias"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert {m["strain"]["window_size"] for m in eng.seen} == {5, 7}
    res = json.loads((out / "results.json").read_text())
    assert res["rank_by"] == "rms_strain_bias" and len(res["ranking"]) == 2
    for r in res["ranking"]:
        assert r["strain_formulation"] == "GREEN" and r["strain_element"] == 9
        assert r["rms_strain_bias"] == pytest.approx(BIAS, rel=1e-6)
        assert r["median_strain_noise"] == pytest.approx(SPREAD, rel=1e-6)       # std of (−s, 0, s), ddof = 1
        assert r["p95_abs_strain_error"] == pytest.approx(BIAS + SPREAD, rel=1e-6)   # the top third
        assert r["strain_noise_floor"] == pytest.approx(SPREAD * math.sqrt(2 / 3), rel=1e-6)
        n = r["strain_points"]
        assert r["strain_valid_share"] == pytest.approx(1 - math.ceil(n / 5) / n)
    rows = (out / "rows.csv").read_text()
    assert "p95_abs_strain_error" in rows.splitlines()[0]
    html = (out / "report.html").read_text()
    assert "strain_noise_floor" in html and "rms_strain_bias" in html
    # resumed: no engine call
    calls = eng.calls
    assert main([str(spec), "-o", str(out), "-q"]) == 0 and eng.calls == calls


# ---- stereo: the surface strain ----------------------------------------------------------------------
def strained_stereo_plate() -> dict:
    """tests/_design.py's stereo plate (turned 10° about y, 20° rig) with the affine field G too."""
    sc = stereo_plate(sigma=1.0, bit_depth=8)
    sc["specimen"]["field"] = {"affine": {"gradient": G}}
    return sc


@pytest.mark.parametrize("formulation", ["GREEN", "HENCKY", "BIOT_EULER"])
def test_surface_truth_of_a_turned_plate_is_the_measure_of_I_plus_G_in_the_plates_axes(formulation):
    """The plate turned about y: camera 0's x projected onto it is the plate's x axis and n × t₁ its
    y axis (pyvale's tangent basis), so the surface strain is the measure of I + G (G in the plate's
    own axes, as [specimen.field] gives it), with the out-of-plane row and column of the identity."""
    from glsim.workflows.design import stereo
    scene = scene_from_dict(strained_stereo_plate(), ".")
    base = planar.Prepared(scene, "cam0", 1, specimen_mesh(scene), None, np.zeros((256, 256)), None, None)
    prep = stereo.StereoPrepared(base, "cam1")
    rng = np.random.default_rng(1)
    x, y = rng.uniform(50, 206, 40), rng.uniform(50, 206, 40)
    t = strain.surface_truth(lambda a, b: stereo._points(prep, a, b), x, y, formulation)
    want = reference_strain(np.eye(2) + np.array(G), formulation)
    assert t["truth_strain_valid"].all()
    np.testing.assert_allclose(t["truth_exx"], want[0, 0], atol=1e-9)
    np.testing.assert_allclose(t["truth_eyy"], want[1, 1], atol=1e-9)
    np.testing.assert_allclose(t["truth_exy"], want[0, 1], atol=1e-9)


class StereoStrainStandIn(_design.StandIn):
    """tests/_design.py's stereo stand-in plus, at its subset centres, the surface strain of I + G
    (scipy) + BIAS + the realisation's offset (−1, 0, +1)·SPREAD in the deformed state, the offset
    alone in the static state, 0 in the reference."""

    def measure(self, exchange: Path):
        off = (-1, 0, 1)[self.calls % 3] * SPREAD
        m = super().measure(exchange)
        manifest = self.seen[-1][1]
        eps = reference_strain(np.eye(2) + np.array(G), manifest["strain"]["strain_formulation"])
        n = len(m.x)
        comp = {k: np.stack([np.zeros(n), np.full(n, off), np.full(n, eps[i, j] + BIAS + off)])
                for k, (i, j) in (("exx", (0, 0)), ("eyy", (1, 1)), ("exy", (0, 1)))}
        return dataclasses.replace(m, strain_x=m.x, strain_y=m.y, strain_valid=np.ones((3, n), bool), **comp)


@pytest.mark.slow   # glsim design end to end
def test_stereo_strain_maps_and_criteria_against_injected_errors(tmp_path, monkeypatch):
    import glsim.workflows.design.cli as cli
    scene = scene_from_dict(strained_stereo_plate(), ".")
    eng = StereoStrainStandIn(scene, 1)
    monkeypatch.setattr(cli, "make_engine", lambda name: eng)
    spec = write_spec(tmp_path / "spec.toml", strained_stereo_plate(), engine="pyvale3d",
                      dic={"subset_size": [31], "subset_step": 16, "strain_window": 5, "strain_formulation": "HENCKY"},
                      realisations={"noise_seeds": [1, 2, 3]}, rank={"by": "strain_noise_floor"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert eng.seen[0][1]["strain"] == {"window_size": 5, "window_element": 9, "strain_formulation": "HENCKY"}
    r = json.loads((out / "results.json").read_text())["ranking"][0]
    assert r["rms_strain_bias"] == pytest.approx(BIAS, rel=1e-6)
    assert r["median_strain_noise"] == pytest.approx(SPREAD, rel=1e-6)
    assert r["p95_abs_strain_error"] == pytest.approx(BIAS + SPREAD, rel=1e-6)
    assert r["strain_noise_floor"] == pytest.approx(SPREAD * math.sqrt(2 / 3), rel=1e-6)
    assert r["rms_bias_W_mm"] == pytest.approx(_design.BIAS["W"], rel=1e-6)     # the displacement maps as before
    html = (out / "report.html").read_text()
    assert "strain_noise_floor" in html
