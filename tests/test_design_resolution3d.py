"""glsim design's spatial resolution beyond the 2-D displacement sweep: the stereo sweep (an
out-of-plane sinusoid W on a plate facing the stereo bisector, engine pyvale3d) and the strain's
spatial resolution (pyvale's exx of the 2-D sweep against the analytic strain). Without the engine:
the plate's axes, the sweep's truth, the analytic strain's amplitude, the spec's criteria and the
report's figures; with pyvale (.venv-verify, marker engine): noise-free sweeps against the subset
average's (and the strain window's) theory within the engine's S-curve bias."""
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from glsim.io.fe import specimen_mesh
from glsim.scene import scene_from_dict
from glsim.workflows.design import report as rep
from glsim.workflows.design import resolution as rs
from glsim.workflows.design.cli import main
from glsim.workflows.design.engine import Pyvale2D, Pyvale3D
from glsim.workflows.design.spec import check_design
from glsim.workflows.library.spec import SpecError

from _design import plate_rotation, plate_scene, s_curve_gain, stereo_plate, write_spec

HALF_ANGLE = math.radians(10.0)     # stereo_plate's rig: 20°, the plate turned by half of it


def _sinc(x):
    return np.sin(x) / x


# ---- without the engine -------------------------------------------------------------------------------
def test_the_stereo_plate_faces_the_bisector_with_camera_0s_x_along_it():
    """tests/_design.py's stereo plate is turned by half the stereo angle to face the rig's bisector
    (its rotation written out there): the sweep's plate axes are that rotation's columns."""
    scene = scene_from_dict(stereo_plate(), ".")
    axes = rs.bisector_axes(scene.camera("cam0"), scene.camera("cam1"), np.array([0.0, 0.0, 300.0]))
    np.testing.assert_allclose(axes, plate_rotation(), atol=1e-12)


def test_the_stereo_sweeps_truth_is_the_imposed_normal_sinusoid():
    """At camera-0 pixels over the plate: the material point moves along the plate's normal only,
    by A·sin(2πx/p) (x its plate coordinate, px) within the bilinear interpolation of 32 nodes a
    period (≤ (πh/p)²/2·A between nodes: 0.5 % of A); the fitted truth keeps ≥ 99 % of A."""
    scene = scene_from_dict(stereo_plate(shift_mm=(0.0, 0.0, 0.0)), ".")
    periods, amp = (32.0, 64.0, 128.0), 0.5
    sw = rs.stereo_sweep_plate(scene, ("cam0", "cam1"), np.mean(specimen_mesh(scene).nodes, axis=0), periods, amp)
    assert sw.mm_per_px == pytest.approx(0.1)
    ys, xs = np.mgrid[30:226:9, 30:226:9].astype(float)
    t = rs.stereo_truth_at(sw, xs.ravel(), ys.ravel())
    assert t["truth_valid"].all()
    np.testing.assert_allclose(t["normal"], plate_rotation()[:, 2], atol=1e-12)   # camera 0 is the world here
    # the plate's x of camera 0's pixels: foreshortened by cos 10° about the centre column (pinhole, written out)
    assert np.ptp(t["x_plate"]) == pytest.approx(np.ptp(xs) / math.cos(HALF_ANGLE), rel=0.03)
    a_mm = amp * sw.mm_per_px
    for k, p in enumerate(periods):
        np.testing.assert_allclose(t["truth_w"][k], a_mm * np.sin(2 * np.pi * t["x_plate"] / p), atol=0.005 * a_mm)
        assert 0.99 < rs.fit_amplitude(t["x_plate"], t["truth_w"][k], p) / a_mm <= 1 + 1e-9


def test_analytic_strain_amplitude_green_and_hencky():
    """exx of u = A·sin(2πx/p): GREEN's is g + g²/2 with g = A·(2π/p)·cos — its fundamental is A·2π/p;
    HENCKY's is ln(1 + g), whose fundamental is 2r, r = (1 − √(1 − a²))/a (a = A·2π/p: the Fourier
    series ln(1 + a·cos φ) = ln((1 + √(1 − a²))/2) + 2 Σ (−1)ⁿ⁺¹ rⁿ/n · cos nφ)."""
    p, A = 40.0, 2.0
    x = np.linspace(-3 * p, 3 * p, 2401)[:-1]          # whole periods, uniform: harmonics orthogonal
    a = A * 2 * np.pi / p
    assert rs.fit_amplitude(x, rs.analytic_strain(x, p, A, "GREEN"), p) == pytest.approx(a, rel=1e-12)
    r = (1 - math.sqrt(1 - a * a)) / a
    assert rs.fit_amplitude(x, rs.analytic_strain(x, p, A, "HENCKY"), p) == pytest.approx(2 * r, rel=1e-12)
    assert 2 * r > a                                  # the logarithm's cubic term adds to the fundamental
    assert np.isnan(rs.analytic_strain(np.array([np.nan]), p, A, "GREEN")).all()


def _spec(tmp_path, **top) -> dict:
    return {"dic": {"subset_size": [21], "subset_step": 10}, **top, "scene": stereo_plate()}


@pytest.mark.parametrize("top, message", [
    ({"engine": "pyvale3d", "rank": {"by": "mei_W_mm2"}}, "rank.by: 'mei_W_mm2' needs the sinusoid sweep"),
    ({"engine": "pyvale3d", "rank": {"by": "spatial_resolution_mm"}}, "needs the sinusoid sweep"),
    ({"engine": "pyvale3d", "resolution": {"periods_px": [32, 64]}, "rank": {"by": "mei_px2"}},
     "'mei_px2' is a 2-D criterion"),
    ({"engine": "pyvale3d", "resolution": {"periods_px": [32, 64]}, "rank": {"by": "strain_mei_px"}},
     "asks for no strain"),
    ({"engine": "pyvale2d", "camera": "cam0", "resolution": {"periods_px": [32, 64]},
      "rank": {"by": "strain_spatial_resolution_px"}}, "asks for no strain"),
    ({"engine": "pyvale2d", "camera": "cam0", "rank": {"by": "mei_W_mm2"}}, "is a stereo criterion"),
])
def test_resolution_criteria_are_checked_by_key(tmp_path, top, message):
    with pytest.raises(SpecError, match=message.replace("(", r"\(").replace("[", r"\[")):
        check_design(_spec(tmp_path, **top), tmp_path)


def test_resolution_criteria_accepted_where_they_are_measured(tmp_path):
    d = check_design(_spec(tmp_path, engine="pyvale3d", resolution={"periods_px": [32, 64]},
                           rank={"by": "mei_W_mm2"}), tmp_path)
    assert d.rank_by == "mei_W_mm2" and d.stereo
    d = check_design({"dic": {"subset_size": [21], "subset_step": 10, "strain_window": [5]}, "engine": "pyvale2d",
                      "resolution": {"periods_px": [32, 64]}, "rank": {"by": "strain_mei_px"},
                      "scene": plate_scene(size=(256, 256))}, tmp_path)
    assert d.rank_by == "strain_mei_px"


def _sweep(ratio, periods=(40.0, 80.0, 160.0), **more) -> dict:
    return {"meta": {"key": "k", "kind": "pyvale3d:resolution", "setup": "v", "setting": "s", "subset_size": 21,
                     "subset_step": 10, "shape_function": "affine", "speckle_seed": None, "noise_seed": 1,
                     "seconds": 1.0},
            "x": np.zeros(4), "valid": np.ones((3, 4), bool), "periods_px": np.array(periods),
            "ratio": np.array(ratio), "truth_ratio": np.ones(3), "amplitude_px": np.float64(0.5),
            "node_spacing_px": np.float64(1.25), "engine_seconds": np.float64(0.5), "mm_per_px": np.float64(0.1),
            "spatial_resolution_px": np.float64(rs.spatial_resolution(periods, ratio)), **more}


def test_summaries_and_report_show_the_stereo_and_strain_resolutions():
    """On synthetic sweep rows: the resolution by the crossing of 90 % (log-linear), in mm through
    the plate's mm per px; the strain's likewise from its own ratios; rows.csv's strain and stereo
    columns; the report's sections and figures."""
    stereo_row = _sweep([0.8, 1.0, 1.0], amplitude_mm=np.float64(0.05))
    s = rep._resolution_summary([stereo_row], math.nan)
    assert s["spatial_resolution_px"] == pytest.approx(math.sqrt(40 * 80))
    assert s["spatial_resolution_mm"] == pytest.approx(0.1 * math.sqrt(40 * 80))
    assert "strain_spatial_resolution_px" not in s
    row = rep.row_summary(stereo_row)
    assert row["sweep_amplitude_mm"] == 0.05 and row["spatial_resolution_mm"] == pytest.approx(0.1 * math.sqrt(3200))

    strain_row = _sweep([0.8, 0.95, 1.0], strain_ratio=np.array([0.3, 0.8, 1.0]),
                        truth_strain_ratio=np.array([0.99, 1.0, 1.0]),
                        strain_spatial_resolution_px=np.float64(math.sqrt(80 * 160)))
    s2 = rep._resolution_summary([strain_row], 0.01)
    assert s2["strain_spatial_resolution_px"] == pytest.approx(math.sqrt(80 * 160))
    assert s2["strain_spatial_resolution_mm"] == pytest.approx(0.1 * math.sqrt(80 * 160))
    assert s2["strain_amplitude_ratio"] == [0.3, 0.8, 1.0]
    assert rep.row_summary(strain_row)["strain_spatial_resolution_px"] == pytest.approx(math.sqrt(12800))

    entries = [{"summary": {"setup": "v", "setting": "s", **s, "noise_floor_W_mm": 0.002,
                            "mei_W_mm2": 0.002 * s["spatial_resolution_mm"]}}]
    page = rep._resolution_section(entries, stereo_design=True)
    assert "out-of-plane sinusoid" in page and "Noise versus resolution (W)" in page and page.count("<img") == 2
    entries2 = [{"summary": {"setup": "v", "setting": "s", **s2, "noise_floor_px": 0.01,
                             "strain_noise_floor_exx": 1e-4}}]
    page2 = rep._resolution_section(entries2)
    assert "Strain spatial resolution" in page2 and "strain attenuation versus period" in page2
    assert page2.count("<img") == 4
    assert "mei_W_mm2" in rep.STEREO_COLUMNS and "strain_mei_px" in rep.RANK_COLUMNS


# ---- with the engine ---------------------------------------------------------------------------------
@pytest.mark.process
@pytest.mark.slow
@pytest.mark.engine
def test_stereo_sweep_attenuation_follows_the_foreshortened_subset_average(tmp_path):
    """Noise-free 16-bit images of tests/_design.py's 20° rig, W = A·sin(2πx/p) along the normal of
    the plate facing the bisector (A = 0.5 px = 0.05 mm), subsets 15 and 31 px (affine), pyvale3d.
    Independent reference: each camera's subset averages the field over its footprint on the plate,
    L px of camera 0 foreshortened to L/cos 10° plate px, keeping sinc(πL/(p·cos 10°)). The motions
    in the images are small (A·sin 10° ≈ 0.09 px in each camera), where pyvale's S-curve is a gain
    error: the measured ratio over the sinc within the S-curve's largest relative bias (0.051,
    bench/results/sweep.json). Attenuation grows with the subset; the FE field keeps ≥ 99 %."""
    why = Pyvale3D().missing()
    if why:
        pytest.skip(f"needs pyvale's environment: {why}")
    sizes, periods = (15, 31), [48.0, 64.0, 96.0, 128.0, 192.0]
    spec = write_spec(tmp_path / "spec.toml", stereo_plate(shift_mm=(0.0, 0.0, 0.0)), engine="pyvale3d",
                      dic={"subset_size": list(sizes), "subset_step": 10}, realisations={"noise_seeds": [1]},
                      resolution={"periods_px": periods, "amplitude_px": 0.5}, rank={"by": "mei_W_mm2"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    res = json.loads((out / "results.json").read_text())
    by = {r["subset_size"]: r for r in res["ranking"]}
    gain = s_curve_gain()
    assert 0.04 < gain < 0.06
    for s in sizes:
        r = by[s]
        ratio = np.array(r["amplitude_ratio"])
        theory = _sinc(np.pi * s / (np.array(periods) * math.cos(HALF_ANGLE)))
        print(f"subset {s}: ratio {np.round(ratio, 4)}, theory {np.round(theory, 4)}, resolution "
              f"{r['spatial_resolution_px']:.1f} px = {r['spatial_resolution_mm']:.2f} mm")
        np.testing.assert_array_less(np.abs(ratio / theory - 1), gain)
        assert min(r["truth_amplitude_ratio"]) > 0.99
        assert r["spatial_resolution_mm"] == pytest.approx(0.1 * r["spatial_resolution_px"])
        assert r["mei_W_mm2"] == pytest.approx(r["noise_floor_W_mm"] * r["spatial_resolution_mm"])
        # the ratios lie between the theory × (1 ∓ gain), so the resolution (the same interpolation at the
        # same periods, monotone in the ratios) between theirs
        lo, hi = (rs.spatial_resolution(periods, theory * (1 + f * gain)) for f in (1, -1))
        assert lo <= r["spatial_resolution_px"] <= hi
    assert np.all(np.array(by[31]["amplitude_ratio"]) < np.array(by[15]["amplitude_ratio"]))
    assert by[31]["spatial_resolution_px"] > by[15]["spatial_resolution_px"]
    header = (out / "ranking.csv").read_text().splitlines()[0].split(",")
    assert {"spatial_resolution_mm", "mei_W_mm2", "amplitude_ratio"} <= set(header)
    sweeps = [r for r in res["rows"] if r["kind"].endswith(":resolution")]
    assert len(sweeps) == 2 and all(r["sweep_amplitude_mm"] == pytest.approx(0.05) for r in sweeps)
    page = (out / "report.html").read_text()
    assert "out-of-plane sinusoid" in page and "Noise versus resolution (W)" in page


def _window_slope_gain(period: float, step: int, window: int) -> float:
    """A full N × N strain window's least-squares slope of sin(kx) at its centre over k (its
    x-coefficient; Q4's and Q9's alike on a symmetric window: the even terms are orthogonal to x),
    centres every ``step`` px: Σ x·sin(kx) / (k·Σ x²)."""
    k = 2 * np.pi / period
    x = step * np.arange(-(window // 2), window // 2 + 1)
    return float(np.sum(x * np.sin(k * x)) / (k * np.sum(x * x)))


# ---- pyvale's strain window, written out: the last stage of the strain references ----------------------
def _grid_index(x: np.ndarray, y: np.ndarray, at=None):
    """pyvale's matrix layout of the subset centres (x, y): the grid of their distinct y and x, and the
    (row, column) there of the points ``at`` (x, y; default the centres), each asserted on the grid."""
    xs, ys = np.unique(x), np.unique(y)
    ax, ay = (x, y) if at is None else at
    rows = np.minimum(np.searchsorted(ys, ay), len(ys) - 1)
    cols = np.minimum(np.searchsorted(xs, ax), len(xs) - 1)
    assert np.array_equal(ys[rows], ay) and np.array_equal(xs[cols], ax)
    return (rows, cols), (len(ys), len(xs))


def _on_grid(values: np.ndarray, index, shape) -> np.ndarray:
    g = np.full(shape, np.nan)
    g[index] = values
    return g


def _q9_window_slope(cx: np.ndarray, cy: np.ndarray, field: np.ndarray, centres, window: int) -> np.ndarray:
    """∂field/∂x at each centre (row, column) as pyvale's strain computes it (pyvale/strain/cpp/strain.cpp
    fill_window_2d/3d, smooth.cpp fit_displacements): the window × window grid nodes around the centre,
    clipped at the grid's edge, the NaN ones left out; least squares of the Q9 polynomial 1, x, y, xy, x²,
    y², x²y, xy², x²y² in the nodes' offsets (cx, cy) from the centre's; the x coefficient. NaN under 9
    nodes or short of rank 9 (pyvale leaves that window out)."""
    h, (R, C) = window // 2, field.shape
    out = np.full(len(centres[0]), np.nan)
    for n, (r, c) in enumerate(zip(*centres)):
        win = (slice(max(0, r - h), min(R, r + h + 1)), slice(max(0, c - h), min(C, c + h + 1)))
        x, y, f = cx[win] - cx[r, c], cy[win] - cy[r, c], field[win]
        ok = np.isfinite(f) & np.isfinite(x) & np.isfinite(y)
        x, y, f = x[ok], y[ok], f[ok]
        if len(f) < 9:
            continue
        D = np.stack([np.ones_like(x), x, y, x * y, x * x, y * y, x * x * y, x * y * y, x * x * y * y], axis=1)
        scale = np.linalg.norm(D, axis=0)              # pyvale scales the columns before its rank test
        if np.linalg.matrix_rank(D / scale) < 9:
            continue
        out[n] = np.linalg.lstsq(D / scale, f, rcond=None)[0][1] / scale[1]
    return out


def test_the_written_out_window_keeps_the_full_windows_slope_gain_inside_and_not_at_the_edge():
    """Inside the grid the written-out Q9 window's slope of sin(kx) is Σx·sin(kx)/(kΣx²) · k·cos(kx₀)
    (the symmetric window's identity above); a window truncated by the grid's edge is not — why the
    strain references run the window on the engine's own grid rather than use the identity."""
    step, p, n = 8, 48.0, 5
    xs = step * np.arange(29, dtype=float)
    gx, gy = np.meshgrid(xs, xs)
    k = 2 * np.pi / p
    rows, cols = np.meshgrid(np.arange(29), np.arange(29), indexing="ij")
    s = _q9_window_slope(gx, gy, np.sin(k * gx), (rows.ravel(), cols.ravel()), n).reshape(29, 29)
    expect = _window_slope_gain(p, step, n) * k * np.cos(k * gx)
    np.testing.assert_allclose(s[2:-2, 2:-2], expect[2:-2, 2:-2], rtol=0, atol=1e-12)
    assert np.max(np.abs(s[:, 0] - expect[:, 0])) > 0.1 * k


@dataclasses.dataclass(frozen=True)
class _Window:
    """pyvale's strain window on a resolution row's subset grid: the window coordinates ``cx``, ``cy``
    of the grid's nodes, the subset centres' (row, column) ``index`` in the grid of ``shape``, the
    strain points' ``centres`` and the window's ``size``."""
    cx: np.ndarray
    cy: np.ndarray
    index: tuple
    shape: tuple
    centres: tuple
    size: int


def _window(z, cx: np.ndarray, cy: np.ndarray, size: int) -> _Window:
    index, shape = _grid_index(z["x"], z["y"])
    centres, _ = _grid_index(z["x"], z["y"], at=(z["strain_x"], z["strain_y"]))
    return _Window(_on_grid(cx, index, shape), _on_grid(cy, index, shape), index, shape, centres, size)


def _reference_ratio(w: _Window, u: np.ndarray, valid: np.ndarray, z, k: int, period: float) -> float:
    """The strain ratio of displacement ``u`` (px per subset centre, its ``valid`` ones) at period k:
    exx (GREEN, v ≡ 0) through the window at the row's strain points (those valid there), fitted as
    resolution.py fits the measured exx, over the analytic exx's fitted amplitude (the row's)."""
    s = _q9_window_slope(w.cx, w.cy, _on_grid(np.where(valid, u, np.nan), w.index, w.shape), w.centres, w.size)
    exx = np.where(z["strain_valid"][k], s + s * s / 2, np.nan)
    return rs.fit_amplitude(z["strain_x_plate"], exx, period) / z["strain_amplitude"][k]


def _bracket(w: _Window, u: np.ndarray, valid: np.ndarray, z, k: int, period: float, gain: float):
    """The reference ratio run on ``u`` scaled by 1 ∓ gain (the S-curve's relative bound): every stage
    after the displacement is linear but GREEN's square, which the run carries exactly."""
    lo, hi = (_reference_ratio(w, f * u, valid, z, k, period) for f in (1 - gain, 1 + gain))
    return min(lo, hi), max(lo, hi)


def _sweep_rows(out: Path, res: dict) -> dict:
    """The resolution rows' arrays (DIR/rows/<key>/result.npz) by setting name."""
    return {r["setting"]: np.load(out / "rows" / r["key"] / "result.npz")
            for r in res["rows"] if r["kind"].endswith(":resolution")}


@pytest.mark.process
@pytest.mark.slow
@pytest.mark.engine
def test_strain_sweep_follows_the_subset_average_and_the_windows_slope(tmp_path):
    """The 2-D sweep with strain windows 5 and 9 (Q9, GREEN), subset 15 px, step 8, noise-free 16-bit.
    Independent reference per period: the affine subset keeps sinc(πL/p) of u, so the subset centres
    the engine returned (the row's x, y, its valid ones) get sinc(πL/p)·A·sin(2πx/p); pyvale's window
    written out (:func:`_q9_window_slope`, edge windows truncated as pyvale's) turns that into exx
    (GREEN, v ≡ 0) at the strain points, fitted as resolution.py fits the measured exx. The written-out
    window is pyvale's: on the measured u, v (the values pyvale's strain read: both from its DIC CSVs) it
    gives pyvale's exx within the strain CSV's 8 decimals, ±5e-9 (and the two solvers' rounding, under
    1e-12 on slopes under 0.1), at the same strain points. The engine's remaining error is its S-curve
    on u (motions ≤ 0.5 px): |bias(s)| ≤ 5.1 %·|s| (bench/results/sweep.json, as the displacement tests)
    bounds the fundamental of bias(u(x)) by 5.1 % of u's, a gain error that the linear window and
    amplitude fits carry unchanged: the measured ratio lies within the reference run on (1 ∓ 5.1 %)·u,
    both windows. Not in the bound: the S-curve's odd harmonics (cut by the window, orthogonal to the
    fitted period over whole periods) and the subsets' scatter, both averaged over ~800 strain points;
    measured, the ratios sit within 2 % of the reference. The wider window attenuates more, at every period, so
    its strain resolution is the larger, both above the displacement's; the FE field's own strain keeps
    ≥ 99 %; the displacement sweep is the same for both settings (same images, same DIC)."""
    if Pyvale2D().missing():
        pytest.skip(f"needs pyvale's environment: {Pyvale2D().missing()}")
    scene = plate_scene(size=(256, 256), shift_px=(0.0, 0.0), bit_depth=16)
    del scene["noise"]
    periods, L, step = [48.0, 64.0, 96.0, 128.0, 192.0, 256.0], 15, 8
    spec = write_spec(tmp_path / "spec.toml", scene, engine="pyvale2d",
                      dic={"subset_size": [L], "subset_step": step, "strain_window": [5, 9], "strain_element": 9,
                           "strain_formulation": "GREEN"},
                      realisations={"noise_seeds": [1]}, resolution={"periods_px": periods},
                      rank={"by": "strain_spatial_resolution_px"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    res = json.loads((out / "results.json").read_text())
    by = {r["strain_window"]: r for r in res["ranking"]}
    arrays = _sweep_rows(out, res)
    gain = s_curve_gain()
    for n, r in sorted(by.items()):
        z = arrays[r["setting"]]
        w = _window(z, z["x"], z["y"], n)          # 2-D: the reference image's px
        assert z["truth_valid"].all()
        for k, p in enumerate(periods):
            ok = z["valid"][k]
            # the written-out window on the measured u, v: pyvale's exx
            su, sv = (_q9_window_slope(w.cx, w.cy, _on_grid(np.where(ok, z[c][k], np.nan), w.index, w.shape),
                                       w.centres, n) for c in ("u", "v"))
            np.testing.assert_array_equal(np.isfinite(su), z["strain_valid"][k])
            on = np.where(z["strain_valid"][k], 1.0, np.nan)
            np.testing.assert_allclose(on * (su + (su * su + sv * sv) / 2), on * z["exx"][k], rtol=0,
                                       atol=5e-9 + 1e-12)
            u = _sinc(np.pi * L / p) * float(z["amplitude_px"]) * np.sin(2 * np.pi * z["x_plate"] / p)
            lo, hi = _bracket(w, u, ok, z, k, p, gain)
            print(f"window {n}, p {p:.0f}: strain ratio {r['strain_amplitude_ratio'][k]:.4f}, reference "
                  f"{_reference_ratio(w, u, ok, z, k, p):.4f} in [{lo:.4f}, {hi:.4f}]")
            assert lo <= r["strain_amplitude_ratio"][k] <= hi
        print(f"window {n}: resolution {r['strain_spatial_resolution_px']:.1f} px "
              f"(displacement {r['spatial_resolution_px']:.1f} px)")
        assert min(r["truth_strain_amplitude_ratio"]) > 0.99
        assert r["strain_spatial_resolution_px"] > r["spatial_resolution_px"]
        assert r["strain_mei_px"] == pytest.approx(r["strain_noise_floor_exx"] * r["strain_spatial_resolution_px"])
    assert np.all(np.array(by[9]["strain_amplitude_ratio"]) < np.array(by[5]["strain_amplitude_ratio"]))
    assert by[9]["strain_spatial_resolution_px"] > by[5]["strain_spatial_resolution_px"]
    # the same images measured twice: equal within the optimiser's stopping tolerance (1e-4 px on A = 0.5 px)
    np.testing.assert_allclose(by[9]["amplitude_ratio"], by[5]["amplitude_ratio"], rtol=0, atol=2e-4)
    assert res["ranking"][0]["strain_window"] == 5
    header = (out / "rows.csv").read_text().splitlines()[0].split(",")
    assert {"strain_spatial_resolution_px", "strain_amplitude_ratio"} <= set(header)
    page = (out / "report.html").read_text()
    assert "Strain spatial resolution" in page and "strain attenuation versus period" in page


def _plate_px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(n, 2) plate x, y (px of 0.1 mm from its centre) of the material point seen at camera-0 pixels
    of tests/_design.py's stereo plate (camera 0 the world: fx = fy = 3000, centre 127.5; the plate
    through (0, 0, 300) mm turned as plate_rotation()): the pixel's ray met with the plate's plane."""
    R, O = plate_rotation(), np.array([0.0, 0.0, 300.0])
    d = np.stack([(x - 127.5) / 3000.0, (y - 127.5) / 3000.0, np.ones_like(x)], axis=1)
    P = d * ((O @ R[:, 2]) / (d @ R[:, 2]))[:, None]
    return (P - O) @ R[:, :2] / 0.1


@pytest.mark.process
@pytest.mark.slow
@pytest.mark.engine
def test_stereo_strain_sweep_follows_the_foreshortened_subset_and_window(tmp_path):
    """A stereo setting with a strain window (5, Q9, GREEN; subset 15, step 8) adds steps moving the
    plate along its own x by U = A·sin(2πx/p); noise-free 16-bit, the 20° rig. References, with camera
    0's px foreshortened by cos 10° on the plate: U keeps sinc(πL/(p·cos 10°)) within the S-curve's
    relative bias (|bias| ≤ 5.1 % of the motion pointwise bounds the fundamental by 5.1 % of A); the
    surface exx: that sinc's U at the valid subset centres through pyvale's window written out, in the
    plate's coordinates of the centres' material points (on a plane pyvale's tangent basis is the
    plate's x, y: t₁ camera 0's x projected onto it, as the sweep's x), GREEN, fitted as resolution.py
    does — the measured ratio within that reference run on (1 ∓ 5.1 %)·U (the S-curve's gain carried by
    the linear fits, as in 2-D); the FE field's own U and strain ≥ 99 %; the strain's resolution above U's."""
    if Pyvale3D().missing():
        pytest.skip(f"needs pyvale's environment: {Pyvale3D().missing()}")
    periods, L, step = [48.0, 64.0, 96.0, 128.0, 192.0, 256.0], 15, 8
    spec = write_spec(tmp_path / "spec.toml", stereo_plate(shift_mm=(0.0, 0.0, 0.0)), engine="pyvale3d",
                      dic={"subset_size": [L], "subset_step": step, "strain_window": [5], "strain_element": 9,
                           "strain_formulation": "GREEN"},
                      realisations={"noise_seeds": [1]}, resolution={"periods_px": periods, "amplitude_px": 0.5},
                      rank={"by": "strain_mei_px"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    res = json.loads((out / "results.json").read_text())
    r = res["ranking"][0]
    z = _sweep_rows(out, res)[r["setting"]]
    c = math.cos(HALF_ANGLE)
    sinc = _sinc(np.pi * L / (np.array(periods) * c))
    gain = s_curve_gain()
    print(f"U ratio {np.round(r['inplane_amplitude_ratio'], 4)} (sinc {np.round(sinc, 4)}); resolutions W "
          f"{r['spatial_resolution_px']:.1f}, U {r['inplane_spatial_resolution_px']:.1f}, exx "
          f"{r['strain_spatial_resolution_px']:.1f} px")
    np.testing.assert_array_less(np.abs(np.array(r["inplane_amplitude_ratio"]) - sinc), gain)
    plate = _plate_px(z["x"], z["y"])
    # the same ray and plane as the sweep's own plate x: equal to float rounding (~1e-13 px on ±150 px)
    np.testing.assert_allclose(plate[:, 0], z["x_plate"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(_plate_px(z["strain_x"], z["strain_y"])[:, 0], z["strain_x_plate"], rtol=0, atol=1e-9)
    w = _window(z, plate[:, 0], plate[:, 1], 5)
    for k, p in enumerate(periods):
        ok = np.isfinite(z["u_along"][k])           # the in-plane state's valid subsets (NaN where not)
        u = sinc[k] * float(z["amplitude_px"]) * np.sin(2 * np.pi * plate[:, 0] / p)
        lo, hi = _bracket(w, u, ok, z, k, p, gain)
        print(f"p {p:.0f}: strain ratio {r['strain_amplitude_ratio'][k]:.4f}, reference "
              f"{_reference_ratio(w, u, ok, z, k, p):.4f} in [{lo:.4f}, {hi:.4f}]")
        assert lo <= r["strain_amplitude_ratio"][k] <= hi
    assert min(r["truth_inplane_amplitude_ratio"]) > 0.99 and min(r["truth_strain_amplitude_ratio"]) > 0.99
    assert r["strain_spatial_resolution_px"] > r["inplane_spatial_resolution_px"]
    assert r["strain_mei_px"] == pytest.approx(r["strain_noise_floor_exx"] * r["strain_spatial_resolution_px"])
    page = (out / "report.html").read_text()
    assert "Strain spatial resolution (stereo)" in page
