"""glsim's side of the rigid-body sweep (no pyvale needed): the exact/procedural renders equal
the exactly shifted speckle model, the px → mm conversion, the generator-alone shift estimator,
the exchange folder, the analysis of (synthetic) DIC results, the frontier plot and the CLI."""
import json
import math
from pathlib import Path

import numpy as np
import pytest
import tifffile

from glsim.scene import speckle
from glsim.dic import cli, frontier, sweep, sweep_report
from glsim.scene.camera import project
from glsim.render import Renderer

SIZE = (96, 96)
SHIFTS = (0.0, 0.3, 0.7)
F32_ULP = 2.0 ** -23        # float32 spacing just below 1.0: grey levels are in [0, 1]


@pytest.fixture(scope="module")
def cpu() -> Renderer:
    r = Renderer(sweep.sweep_scene(SIZE, SHIFTS), backend="cpu")
    yield r
    r.close()


def _pair(r: Renderer, spp: int):
    seq = {"name": "x", "source": "glsim", "mode": "exact", "interpolation": "procedural", "spp": spp}
    rendered, ref, _ = sweep.render_sequence(r, seq, len(SHIFTS))
    model, mref, _ = sweep.render_sequence(r, {**seq, "source": "model"}, len(SHIFTS))
    return [ref] + rendered, [mref] + model


# ---- the generator has no bias in exact/procedural mode ----------------------------------------
@pytest.mark.parametrize("spp", [1, 4])
def test_exact_procedural_equals_exactly_shifted_model(cpu, spp):
    """Every image of the sequence (reference and each shift) equals the speckle model evaluated
    at the exactly shifted reference coordinates, to float32 precision."""
    rendered, model = _pair(cpu, spp)
    for a, b in zip(rendered, model):
        assert a.dtype == b.dtype == np.float32
        assert np.max(np.abs(a.astype(np.float64) - b)) <= 2 * F32_ULP
    # and the sequence really moves: consecutive shifts differ by far more than that
    assert np.max(np.abs(rendered[2].astype(np.float64) - rendered[3])) > 0.1


@pytest.mark.gl
def test_exact_procedural_equals_model_gl(gl_ctx):
    """The GL shader evaluates the dots in float32 at reference coordinates of ~10² px: its
    images match the model to float32 rounding of those coordinates (≤ 5e-5 of full scale =
    ~1e-4 px × the steepest dot edge, 0.6 per reference px), far below a 16-bit step (1.5e-5
    is half a step: measured 7e-6 at 512×512)."""
    with Renderer(sweep.sweep_scene(SIZE, SHIFTS), backend="gl", ctx=gl_ctx) as r:
        rendered, model = _pair(r, 1)
    for a, b in zip(rendered, model):
        assert np.max(np.abs(a.astype(np.float64) - b)) <= 5e-5


# ---- shifts in px and mm -------------------------------------------------------------------------
def test_shift_px_to_mm():
    cam = sweep.camera()
    assert sweep.mm_per_px(cam) == pytest.approx(sweep.DISTANCE / sweep.FX, rel=1e-15)   # 0.1 mm/px
    assert sweep.shifts_mm([0.0, 0.5, 1.0], 0.1) == ((0.0, 0.0, 0.0), (0.05, 0.0, 0.0), (0.1, 0.0, 0.0))
    scene = sweep.sweep_scene((256, 256), (0.25, 1.0))
    scale = sweep.mm_per_px(scene.cameras[0])
    assert scale == pytest.approx(2 * 0.1)                      # fx scales with the width
    assert scene.specimen.plate.translations == sweep.shifts_mm((0.25, 1.0), scale)
    # A point anywhere on the plate moves by exactly the shift in px (the plate is square to the camera).
    cam = scene.cameras[0]
    X = np.array([[x, y, sweep.DISTANCE] for x in (-10.0, 0.0, 7.0) for y in (-8.0, 3.0)])
    uv0, _ = project(X, cam)
    for s, t in zip((0.25, 1.0), scene.specimen.plate.translations):
        uv, _ = project(X + np.asarray(t), cam)
        np.testing.assert_allclose(uv - uv0, [[s, 0.0]] * len(X), atol=1e-12)


# ---- generator-alone shift estimator ----------------------------------------------------------
def test_apparent_shift_recovers_model_shifts(cpu):
    scene, ref = cpu.scene, cpu.reference
    scale = sweep.mm_per_px(scene.cameras[0])
    grid = speckle.dot_grid(ref.dots)
    roi = sweep.roi_mask(cpu, len(SHIFTS) + 1)
    model_at = lambda su, sv: sweep.model_image(scene, ref, (su * scale, sv * scale, 0.0), 1, grid,  # noqa: E731
                                                 np.float64, roi)
    img = lambda su, sv: sweep.model_image(scene, ref, (su * scale, sv * scale, 0.0), 1, grid, np.float64)  # noqa: E731
    exact, off = sweep.apparent_shift([img(0.3, 0.0), img(0.32, -0.01)], model_at, 0.3, roi)
    assert max(map(abs, exact)) < 1e-9                      # the model's own image: no error
    assert off == pytest.approx((0.02, -0.01), abs=2e-5)    # a known extra shift is recovered
    # the pixel subset evaluation is the full image's
    np.testing.assert_array_equal(model_at(0.3, 0.0), img(0.3, 0.0)[roi])


# ---- exchange folder ---------------------------------------------------------------------------
SEQS = (sweep.SEQUENCES[0], sweep.SEQUENCES[1], sweep.SEQUENCES[2])   # model, exact-procedural, exact-bspline3
RUN = {"name": "s11", "subset_size": 11}


@pytest.fixture(scope="module")
def exchange(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sweep")
    # 0.3 px: the reference image's pixels lie on the plate's lattice (issue 29), on which this
    # camera's pixel centres fall at whole and half-pixel shifts, where bspline3 is exact
    sweep.write_exchange(out, size=SIZE, shifts_px=(0.0, 0.3), sequences=SEQS, backend="cpu", runs=[RUN])
    return out


def test_exchange_layout(exchange):
    m = json.loads((exchange / "manifest.json").read_text())
    assert m["format"] == "glsim-sweep/1" and m["size"] == list(SIZE) and m["bit_depth"] == 16
    assert m["shifts_px"] == [0.0, 0.3]
    assert m["shift_mm"] == pytest.approx([0.0, 0.3 * m["mm_per_px"]])
    assert m["runs"] == [RUN]
    c2 = m["calculate_2d"]
    assert c2["image_filter_kernel"] == 1 and c2["interpolation_routine"] == "BSPLINE" and "subset_size" not in c2
    roi = tifffile.imread(exchange / m["roi"])
    assert roi.dtype == np.uint8 and set(np.unique(roi)) <= {0, 255} and (roi > 0).sum() == m["roi_pixels"] > 0
    x, y = m["seed"]
    assert roi[y, x] == 255
    assert [s["name"] for s in m["sequences"]] == [s["name"] for s in SEQS]
    for s in m["sequences"]:
        assert s["reference"] == f"{s['name']}/reference.tif"
        assert s["deformed"] == [f"{s['name']}/shift_00.tif", f"{s['name']}/shift_01.tif"]
        assert s["reference"] not in s["deformed"]            # pyvale must not see it twice
        for name in [s["reference"]] + s["deformed"]:
            img = tifffile.imread(exchange / name)
            assert img.dtype == np.uint16 and img.shape == SIZE[::-1]
        assert len(s["grey_rms_vs_model"]) == len(s["seconds"]) - 1 == 2
    seqs = {s["name"]: s for s in m["sequences"]}
    assert max(seqs["exact-procedural"]["grey_rms_vs_model"]) <= 2 * F32_ULP
    assert max(seqs["exact-bspline3"]["grey_rms_vs_model"]) > 1e-3
    assert max(map(abs, seqs["exact-procedural"]["apparent_u"])) < 1e-6
    assert "apparent_u" not in seqs["model"]
    # the zero-shift image is the reference image, under another name
    np.testing.assert_array_equal(tifffile.imread(exchange / "model/reference.tif"),
                                  tifffile.imread(exchange / "model/shift_00.tif"))
    assert json.loads((exchange / "scene.json").read_text())["specimen"]["plate"]["translations"][1][0] > 0


# ---- analysis of DIC results, report, frontier -------------------------------------------------
def _fake_dic(exchange: Path, errors: dict) -> None:
    """measured_<seq>_<run>.npz as verify/dic2d.py writes them: u = shift + errors[seq](shift) + a
    zero-mean spread over 6 subsets; v = 0."""
    m = json.loads((exchange / "manifest.json").read_text())
    shifts = np.array(m["shifts_px"])
    spread = np.array([-3, -2, -1, 1, 2, 3]) * 1e-4
    for s in m["sequences"]:
        u = shifts[:, None] + errors[s["name"]](shifts)[:, None] + spread[None, :]
        np.savez(exchange / f"measured_{s['name']}_{RUN['name']}.npz", ss_x=np.arange(6), ss_y=np.zeros(6, int),
                 u=u, v=np.zeros_like(u), valid=np.ones(u.shape, bool), cost=np.ones(u.shape),
                 niter=np.ones(u.shape, int), seconds=np.float64(1.5), pyvale_version=np.str_("test"))


def _accuracy() -> dict:
    recs = []
    for mode, t, map_rms in (("fast", 0.05, 2e-2), ("q4", 0.1, 7e-2), ("exact", 0.2, 1e-12)):
        for interp, k in (("bspline3", 1.0), ("procedural", 1.8)):
            for spp in (1, 4):
                recs.append({"backend": "gl", "mode": mode, "interpolation": interp, "spp": spp,
                             "precision": "fp64", "arithmetic": "fp64", "seconds": t * k * spp,
                             "map_rms_px": map_rms, "map_max_px": 3 * map_rms,
                             "speckle_rms": (3.0 if interp == "bspline3" else 2e-3) / spp})
    recs.append({"backend": "cpu", "mode": "exact", "interpolation": "bspline3", "spp": 1, "precision": "fp64",
                 "arithmetic": "fp64", "seconds": 5.0, "map_rms_px": 0.0, "map_max_px": 0.0, "speckle_rms": 3.0})
    return {"machine": {"gl": {"renderer": "test"}, "cores": 2}, "date": "today", "size": [1624, 1234],
            "scene": "synthetic", "records": recs}


def test_analyse_report_and_frontier(exchange, tmp_path):
    errors = {"model": lambda s: 0.004 * np.sin(2 * np.pi * s + 0.3),
              "exact-procedural": lambda s: 0.004 * np.sin(2 * np.pi * s + 0.3),
              "exact-bspline3": lambda s: 0.004 * np.sin(2 * np.pi * s + 0.3) + 0.001}
    _fake_dic(exchange, errors)
    res = sweep.analyse(exchange)
    by = {r["sequence"]: r for r in res["results"]}
    assert set(by) == {"model", "exact-procedural", "exact-bspline3"}
    for name, r in by.items():
        for row in r["rows"]:
            assert row["bias_u"] == pytest.approx(errors[name](np.array(row["shift_px"])), abs=1e-12)
            assert row["std_u"] == pytest.approx(np.std(np.array([-3, -2, -1, 1, 2, 3]) * 1e-4))
            assert row["bias_v"] == 0.0
    assert by["exact-bspline3"]["max_abs_gen_u"] == pytest.approx(0.001)
    assert by["exact-procedural"]["max_abs_gen_u"] == pytest.approx(0.0, abs=1e-15)
    assert by["model"]["max_abs_gen_u"] is None
    assert by["exact-procedural"]["max_abs_apparent_u"] < 1e-6

    acc = tmp_path / "accuracy.json"
    acc.write_text(json.dumps(_accuracy()))
    results = tmp_path / "results"
    sweep_report.report(exchange, results, acc)
    for name in ("sweep.json", "sweep.png", "sweep.md", "frontier.png"):
        assert (results / name).stat().st_size > 0
    md = (results / "sweep.md").read_text()
    assert "## S-curve amplitudes" in md and "## Frontier" in md and "## Which default" in md
    assert json.loads((results / "sweep.json").read_text())["results"][0]["sequence"] == "model"


def test_frontier_from_synthetic_accuracy(tmp_path):
    """`frontier` needs only accuracy.json (the sweep panel is added when sweep.json exists)."""
    (tmp_path / "accuracy.json").write_text(json.dumps(_accuracy()))
    assert cli.main(["frontier", "--results", str(tmp_path)]) == 0
    assert (tmp_path / "frontier.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    md = (tmp_path / "sweep.md").read_text()
    assert "Pareto" in md and "S-curve" in md          # title only: no sweep measured
    assert "## S-curve amplitudes" not in md
    assert cli.main(["frontier", "--results", str(tmp_path / "none")]) == 2   # no accuracy.json


def test_pareto():
    pts = [(1.0, 5.0), (2.0, 1.0), (1.5, 6.0), (3.0, 1.0), (0.5, 9.0), (4.0, 0.5)]
    assert frontier.pareto(pts) == [4, 0, 1, 5]


def test_verify_cli_has_sweep_and_frontier():
    ap = cli.parser()
    a = ap.parse_args(["sweep", "--size", "256", "256", "--exchange", "x"])
    assert (a.command, a.size, a.exchange, a.results) == ("sweep", [256, 256], "x", "bench/results")
    a = ap.parse_args(["frontier", "--accuracy", "acc.json"])
    assert (a.command, a.accuracy) == ("frontier", "acc.json")
    assert math.isclose(sweep.SHIFTS_PX[-1], 1.0) and len(sweep.SHIFTS_PX) == 11


def test_backend_agreement_reports_the_largest_differences():
    def seq(name, source, biases, stds, run="s21"):
        return {"sequence": name, "run": run, "source": source, "max_std_u": max(stds),
                "rows": [{"bias_u": b, "std_u": s} for b, s in zip(biases, stds)]}

    gl = {"machine": {}, "results": [seq("model", "model", [0, 1e-3], [0, 2e-2]),
                                     seq("exact-bspline3", "glsim", [0, 2e-3], [0, 1e-2])]}
    cpu = {"machine": {}, "results": [seq("exact-bspline3", "glsim", [0, 2.5e-3], [0, 1.2e-2])]}
    (row,) = sweep_report.backend_agreement(gl, cpu)["rows"]
    assert row["sequence"] == "exact-bspline3" and row["dic_noise_px"] == 2e-2
    assert row["max_delta_bias_px"] == pytest.approx(5e-4) and row["max_delta_std_px"] == pytest.approx(2e-3)
    assert "| exact-bspline3 | s21 | 5.00e-04 |" in sweep_report.backend_markdown(sweep_report.backend_agreement(gl, cpu))


def test_too_small_sweep_is_refused_with_the_fix(capsys):
    assert cli.main(["sweep", "--size", "160", "160", "--exchange", "/nonexistent/x"]) == 2
    err = capsys.readouterr().err
    assert "--size 160 160" in err and "--size 512 512" in err
