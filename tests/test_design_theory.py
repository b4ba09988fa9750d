"""glsim design against theory: the sinusoid sweep's pieces (the FE field's own attenuation, the
fit, the 90 % crossing) and, with pyvale's 2-D DIC (.venv-verify), zero bias on noise-free exact
images of a rigid sub-pixel shift and the sinusoid's attenuation growing with the subset size."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from glsim.io.fe import specimen_mesh
from glsim.scene import scene_from_dict
from glsim.workflows.design import resolution as rs
from glsim.workflows.design.cli import main
from glsim.workflows.design.engine import Pyvale2D

import _design
from _design import write_spec

REPO = Path(__file__).resolve().parents[1]


def plate_scene(size=(256, 256), shift_px=(0.0, 0.0), sigma=1.0, bit_depth=8) -> dict:
    """The design tests' plate (tests/_design.py), larger, still and 8-bit by default."""
    return _design.plate_scene(size, shift_px, sigma, bit_depth)


SINC_90 = brentq(lambda x: np.sin(x) / x - 0.9, 0.1, 1.5)     # 0.786


def _needs_pyvale():
    why = Pyvale2D().missing()
    if why:
        pytest.skip(f"needs pyvale's environment: {why}")


# ---- the sweep's pieces, without an engine ---------------------------------------------------------
def test_fit_recovers_a_sinusoid_and_refuses_aliased_phases():
    rng = np.random.default_rng(2)
    x = rng.uniform(-100, 100, 400)
    u = 0.37 * np.sin(2 * np.pi * x / 40 + 0.6) + 0.1
    assert rs.fit_amplitude(x, u, 40.0) == pytest.approx(0.37, rel=1e-12)
    grid = np.arange(-96.0, 100.0, 8.0)          # centres every 8 px: two phases of a 16 px period
    assert math.isnan(rs.fit_amplitude(grid, np.sin(2 * np.pi * grid / 16 + 0.3), 16.0))


def test_spatial_resolution_is_the_largest_crossing_of_ninety_percent():
    # log-linear between 40 (0.8) and 80 (1.0): 0.9 halfway in log → √(40·80)
    assert rs.spatial_resolution([20, 40, 80], [0.3, 0.8, 1.0]) == pytest.approx(math.sqrt(40 * 80))
    # a sidelobe above 0.9 at a short period does not count: the last crossing from below does
    assert rs.spatial_resolution([10, 20, 40, 80], [0.95, 0.2, 0.85, 0.95]) == pytest.approx(
        math.exp(math.log(40) + 0.5 * math.log(2)))
    assert math.isnan(rs.spatial_resolution([20, 40], [0.5, 0.8]))     # not bracketed
    assert math.isnan(rs.spatial_resolution([20, 40], [0.95, 0.99]))


def test_the_fe_field_keeps_the_imposed_amplitude_at_32_nodes_per_period():
    """The truth of the rendered field (Q4, bilinear between nodes every p_min/32) at subset-like
    centres: its fitted amplitude is within 1 % of the imposed one at every period — ten times
    below the 10 % attenuation that defines the spatial resolution. Theory: a linear interpolant
    keeps ≈ 1 − (πh/p)²/3 of a sinusoid's amplitude (0.32 % at h = p/32)."""
    scene = scene_from_dict(plate_scene(size=(256, 256)), ".")
    depth = rs.specimen_depth(scene, "cam0", specimen_mesh(scene))
    assert depth == pytest.approx(300.0)
    periods = (16.0, 32.0, 64.0, 128.0)
    sw = rs.sweep_plate(scene, "cam0", depth, periods, 0.5)
    assert sw.node_spacing_px == pytest.approx(16.0 / 32)
    ys, xs = np.mgrid[20:236:7, 20:236:7].astype(float)
    t = rs.truth_at(sw, xs.ravel(), ys.ravel())
    assert t["truth_valid"].all()
    ratio = [rs.fit_amplitude(t["x_plate"], t["truth_u"][k], p) / 0.5 for k, p in enumerate(periods)]
    assert all(0.99 < r <= 1.0 + 1e-9 for r in ratio), ratio
    assert ratio == sorted(ratio)                 # finer sampling of the period → closer to 1


# ---- with the engine -----------------------------------------------------------------------------
@pytest.mark.process
@pytest.mark.slow
@pytest.mark.engine
def test_rigid_subpixel_shift_on_noise_free_exact_images_has_no_bias_beyond_the_engines_s_curve(tmp_path):
    """A 0.3 px rigid shift (the S-curve's extreme), 16 bits, no noise, exact mode, the default
    speckle (5 px dots), subset 21 affine: the conditions of glsim verify sweep. The engine's
    interpolation bias is that sweep's S-curve (bench/results/sweep.json, the model images — built
    from the speckle model, no renderer — at subset 21 over 1800 subsets): the mean error over
    subsets, u and v, is bounded by its amplitude (max |bias_u| over the shifts, 0.0079 px), u
    with 50 % room for this smaller image's other subset sample; each subset's error by the
    sweep's largest single-subset |u| (max_abs_u over the shifts)."""
    _needs_pyvale()
    sweep = json.loads((REPO / "bench" / "results" / "sweep.json").read_text())
    model = next(r for r in sweep["results"] if r["sequence"] == "model" and r["subset_size"] == 21)
    scene = plate_scene(size=(256, 256), shift_px=(0.3, 0.0), bit_depth=16)
    del scene["noise"]
    scene["speckle"] = {"seed": 0}
    spec = write_spec(tmp_path / "spec.toml", scene, engine="pyvale2d",
                      dic={"subset_size": [21], "subset_step": 10}, realisations={"noise_seeds": [1]},
                      rank={"by": "rms_bias_px"})
    assert main([str(spec), "-o", str(tmp_path / "out"), "-q"]) == 0
    rows = json.loads((tmp_path / "out" / "results.json").read_text())["rows"]
    r = next(x for x in rows if x["kind"] == "pyvale2d")
    assert r["valid_share"] == 1.0
    print(f"mean u error {r['mean_u_error_px']:.5f} px, v {r['mean_v_error_px']:.5f} px; "
          f"p95 |error| {r['p95_abs_error_px']:.4f} px; S-curve amplitude {model['max_abs_bias_u']:.5f} px")
    s_curve = model["max_abs_bias_u"]
    assert abs(r["mean_u_error_px"]) <= 1.5 * s_curve
    assert abs(r["mean_v_error_px"]) <= s_curve
    assert r["p95_abs_error_px"] <= max(row["max_abs_u"] for row in model["rows"])
    assert r["static_std_u_px"] < 1e-3          # a noise-free static pair: no apparent motion


@pytest.mark.process
@pytest.mark.slow
@pytest.mark.engine
def test_sinusoid_attenuation_grows_with_subset_size_and_follows_the_subset_average(tmp_path):
    """Two subsets (15, 31 px, affine) on the same sweep: at every period the 31 px subset keeps
    less of the amplitude, so its spatial resolution is the larger. Independent reference: an
    affine subset's value at its centre is about the subset's mean of u, which keeps
    sinc(πL/p) = sin(πL/p)/(πL/p) of a sinusoid. Bound: pyvale's S-curve measures a motion of
    at most 0.5 px short or long by at most its largest relative bias g (bench/results/sweep.json,
    ~5 %), so the fitted amplitude within g·sinc; the image noise adds to each of the fit's two
    coefficients a standard deviation σ·√(2/N) (σ the static pair's noise floor, N subsets), so
    4σ·√(2/N)/A on the ratio. The resolution lies between those of sinc × (1 ∓ g) widened by that
    noise term."""
    _needs_pyvale()
    sizes, periods = (15, 31), [48.0, 64.0, 96.0, 128.0, 192.0]
    spec = write_spec(tmp_path / "spec.toml", plate_scene(size=(256, 256), shift_px=(0.0, 0.0), sigma=1.0,
                                                          bit_depth=8),
                      engine="pyvale2d", dic={"subset_size": list(sizes), "subset_step": 10},
                      realisations={"noise_seeds": [1]}, resolution={"periods_px": periods},
                      rank={"by": "mei_px2"})
    assert main([str(spec), "-o", str(tmp_path / "out"), "-q"]) == 0
    ranking = json.loads((tmp_path / "out" / "results.json").read_text())["ranking"]
    page = (tmp_path / "out" / "report.html").read_text()
    assert "noise versus resolution frontier" in page and "attenuation versus period" in page
    by = {r["subset_size"]: r for r in ranking}
    small, large = (np.array(by[s]["amplitude_ratio"]) for s in sizes)
    for s in sizes:
        print(f"subset {s}: ratio {np.round(by[s]['amplitude_ratio'], 3)}, resolution "
              f"{by[s]['spatial_resolution_px']:.1f} px, noise floor {by[s]['noise_floor_px']:.4f} px, "
              f"MEI {by[s]['mei_px2']:.3f} px²")
    assert np.all(large < small)
    assert by[31]["spatial_resolution_px"] > by[15]["spatial_resolution_px"]
    gain = _design.s_curve_gain()
    for s in sizes:
        x = np.pi * s / np.array(periods)
        theory = np.sin(x) / x
        r = by[s]
        noise = 4 * r["noise_floor_px"] * math.sqrt(2 / r["subsets"]) / r["sweep_amplitude_px"]
        np.testing.assert_array_less(np.abs(np.array(r["amplitude_ratio"]) - theory), gain * theory + noise)
        lo, hi = (rs.spatial_resolution(periods, theory * (1 + f * gain) + f * noise) for f in (1, -1))
        assert lo <= r["spatial_resolution_px"] <= hi
        assert lo <= np.pi * s / SINC_90 <= hi      # the continuous sinc's own crossing, p = πL/0.786
        assert by[s]["mei_px2"] == pytest.approx(by[s]["noise_floor_px"] * by[s]["spatial_resolution_px"])
        assert min(by[s]["truth_amplitude_ratio"]) > 0.99
