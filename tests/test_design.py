"""glsim design: spec refusals by key (nothing written), the quick mode against theory (SSSIG) and
against a Monte-Carlo of an independent subset matcher, resume and determinism, the HTML report
in a real browser, and the end-to-end run with pyvale's 2-D DIC where .venv-verify exists."""
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from glsim.scene import scene_from_dict
from glsim.workflows.design import planar, quick
from glsim.workflows.design.cli import main
from glsim.workflows.design.engine import Pyvale2D

from _design import plate_scene, write_spec

REPO = Path(__file__).resolve().parents[1]


# ---- refusals ---------------------------------------------------------------------------------------
BAD = [({"dic": {"subset_size": [20]}}, "dic.subset_size"),
       ({"dic": {"subset_size": [21], "shape": "affine"}}, "dic.shape: unknown key"),
       ({"dic": {"subset_size": [21]}, "engine": "dice"}, "engine"),
       ({"dic": {"subset_size": [21]}, "rank": {"by": "noise_floor_px"}}, "rank.by"),
       ({"dic": {"subset_size": [21]}, "calibration": {"rig": "target-library"}}, "calibration.rig"),
       ({"dic": {"subset_size": [21]}, "step": 3}, "step"),
       ({"dic": {"subset_size": [21]}, "realisations": {"noise_seeds": [1, 1]}}, "realisations.noise_seeds"),
       ({"dic": {"subset_size": [21]}, "vary": {"noise.sigmaa": [1.0]}}, "noise.sigmaa"),
       ({"dic": {"subset_size": [21]}, "engine": "pyvale2d"}, "cameras.cam0.size"),
       ({"dic": {}}, "dic.subset_size: is required"),
       ({"dic": {"subset_size": [21]}, "plan": 1}, "plan: unknown key"),
       ({"dic": {"subset_size": [21]}, "resolution": {"periods_px": [32, 64]}}, "resolution: the sinusoid sweep needs"),
       ({"dic": {"subset_size": [21], "subset_step": 10}, "engine": "pyvale2d", "resolution": {"periods_px": [20, 64]}},
        "resolution.periods_px: 20 px is not above twice the subset step"),
       ({"dic": {"subset_size": [21]}, "engine": "pyvale2d", "resolution": {"periods_px": [64]}},
        "resolution.periods_px: [64] has one period"),
       ({"dic": {"subset_size": [21]}, "engine": "pyvale2d", "resolution": {"amplitude_px": 0}},
        "resolution.amplitude_px"),
       ({"dic": {"subset_size": [21]}, "engine": "pyvale2d", "resolution": {"period": [64]}},
        "resolution.period: unknown key"),
       ({"dic": {"subset_size": [21]}, "engine": "pyvale2d", "rank": {"by": "mei_px2"}}, "add a [resolution] table")]


@pytest.mark.parametrize("top,key", BAD)
def test_bad_specs_are_refused_by_key_before_anything_is_written(tmp_path, capsys, top, key):
    spec = write_spec(tmp_path / "spec.toml", plate_scene(), **top)
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert key in err and "Traceback" not in err
    assert not out.exists()


# ---- quick mode against theory ----------------------------------------------------------------------
def test_spline_gradient_is_the_interpolants_derivative():
    """Independent reference: central differences of scipy's own cubic B-spline interpolant."""
    img = ndimage.gaussian_filter(np.random.default_rng(1).random((50, 60)), 1.5)
    gx, gy = quick.spline_gradient(img)
    c = ndimage.spline_filter(img, order=3, mode="mirror")
    Y, X = np.mgrid[8:42, 8:52].astype(float)
    h = 1e-5
    at = lambda y, x: ndimage.map_coordinates(c, [y, x], order=3, prefilter=False, mode="mirror")  # noqa: E731
    np.testing.assert_allclose(gx[8:42, 8:52], (at(Y, X + h) - at(Y, X - h)) / (2 * h), atol=1e-8)
    np.testing.assert_allclose(gy[8:42, 8:52], (at(Y + h, X) - at(Y - h, X)) / (2 * h), atol=1e-8)


def _match_rigid(f, g, centres, h, start, iterations=10):
    """A zero-order subset matcher written for this test: forward-additive Gauss–Newton on
    Σ (g(x + p) − f(x))², g by scipy's cubic B-spline, its gradient by finite differences."""
    cg = ndimage.spline_filter(g, order=3, mode="mirror")
    dy, dx = np.mgrid[-h:h + 1, -h:h + 1]
    out = []
    for cx, cy in centres:
        F = f[cy - h:cy + h + 1, cx - h:cx + h + 1].ravel()
        p = np.array(start, float)
        for _ in range(iterations):
            at = lambda ex, ey: ndimage.map_coordinates(  # noqa: E731
                cg, [cy + dy + p[1] + ey, cx + dx + p[0] + ex], order=3, prefilter=False).ravel()
            G = at(0, 0)
            J = np.stack([(at(1e-4, 0) - G) / 1e-4, (at(0, 1e-4) - G) / 1e-4], axis=1)
            step = np.linalg.lstsq(J, F - G, rcond=None)[0]
            p += step
            if np.abs(step).max() < 1e-7:
                break
        out.append(p.copy())
    return np.array(out)


def test_quick_mode_equals_sssig_and_a_monte_carlo_of_a_subset_matcher():
    """On a flat fronto-parallel plate (16-bit, Gaussian noise σ = 2 % in both images, no
    quantisation): the zero-order quick σ_u equals Pan et al.'s √2·σ/√SSSIG where the subset's
    Σ I_x I_y vanishes (exactly: σ_u² = 2σ²/(Σ I_x² − (Σ I_x I_y)²/Σ I_y²)), and the std of u over
    120 noise realisations of a rigid 2 px shift measured by an independent matcher is within 25 %."""
    from glsim.render import Renderer

    scene = scene_from_dict(plate_scene(), ".")
    prep = planar.prepare(scene, "cam0", 1, 2)
    with Renderer(scene.replace(noise=None), mesh=prep.mesh, reference=prep.reference) as r:
        moved = np.asarray(r.render(0, 1).image, np.float64)
    size, h = 21, 10
    centres = quick.grid_centres(prep.roi, size, 25)[:24]
    variance = quick.pixel_variance(prep.image, scene.noise, 16, quantisation=False)
    sigma = float(np.sqrt(variance[0, 0]))
    assert sigma == pytest.approx(0.02 * 65536 / 65535)
    q = quick.crb(prep.image, variance, centres, size, "rigid")
    # the same sums, formed here from the gradient
    gx, gy = quick.spline_gradient(prep.image)
    for k, (cx, cy) in enumerate(centres):
        X, Y = gx[cy - h:cy + h + 1, cx - h:cx + h + 1], gy[cy - h:cy + h + 1, cx - h:cx + h + 1]
        sxx, syy, sxy = np.sum(X * X), np.sum(Y * Y), np.sum(X * Y)
        assert q["sssig_x"][k] == pytest.approx(sxx)
        assert q["sigma_u"][k] == pytest.approx(np.sqrt(2 * sigma ** 2 / (sxx - sxy ** 2 / syy)), rel=1e-9)
    pan = quick.sssig_sigma(q["sssig_x"], sigma)
    ratio = q["sigma_u"] / pan
    assert np.all(ratio >= 1 - 1e-12) and np.median(ratio) < 1.02, ratio   # the cross term is small on a speckle
    rng = np.random.default_rng(7)
    runs = np.array([_match_rigid(prep.image + sigma * rng.standard_normal(moved.shape),
                                  moved + sigma * rng.standard_normal(moved.shape), centres, h, (2.0, 0.0))
                     for _ in range(120)])
    mc = runs.std(axis=0, ddof=1)
    assert np.median(mc[:, 0] / q["sigma_u"]) == pytest.approx(1.0, abs=0.25)
    assert np.median(mc[:, 1] / q["sigma_v"]) == pytest.approx(1.0, abs=0.25)
    assert np.median(mc[:, 0] / pan) == pytest.approx(1.0, abs=0.25)


def test_quick_sigma_falls_with_subset_size_and_grows_with_the_shape_functions_order():
    scene = scene_from_dict(plate_scene(), ".")
    prep = planar.prepare(scene, "cam0", 1, 2)
    c = np.array([[100, 80], [90, 70]])
    s = {(n, sh): quick.crb(prep.image, prep.variance, c, n, sh)["sigma_u"] for n in (15, 31)
         for sh in ("rigid", "affine", "quad")}
    assert np.all(s[31, "rigid"] < s[15, "rigid"])
    assert np.all(s[15, "rigid"] <= s[15, "affine"]) and np.all(s[15, "affine"] <= s[15, "quad"])


# ---- the command: files, resume, determinism ----------------------------------------------------------
def quick_spec(tmp_path: Path) -> Path:
    return write_spec(tmp_path / "spec.toml", plate_scene(sigma=1.0, bit_depth=8), engine="quick",
                      vary={"noise": {"sigma": [1.0, 3.0]}}, dic={"subset_size": [15, 25], "subset_step": 12})


def test_quick_design_writes_its_files_under_o_resumes_and_repeats(tmp_path, capsys):
    spec = quick_spec(tmp_path)
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "spec.toml"]
    assert {"report.html", "results.json", "ranking.csv", "rows.csv", "rows"} <= {p.name for p in out.iterdir()}
    res = json.loads((out / "results.json").read_text())
    assert res["rank_by"] == "quick_sigma_px" and len(res["ranking"]) == 4 and len(res["rows"]) == 4
    best = res["ranking"][0]
    assert best["params"] == {"noise.sigma": 1.0} and best["subset_size"] == 25
    by = {(r["params"]["noise.sigma"], r["subset_size"]): r["quick_sigma_px"] for r in res["ranking"]}
    # σ scales with the noise (quantisation adds a little at 1 %)
    assert by[3.0, 15] / by[1.0, 15] == pytest.approx(3.0, rel=0.03)
    stamps = {p: p.stat().st_mtime_ns for p in (out / "rows").glob("*/row.json")}
    assert main([str(spec), "-o", str(out), "-q"]) == 0          # resumed: every row reused
    assert {p: p.stat().st_mtime_ns for p in (out / "rows").glob("*/row.json")} == stamps
    again = tmp_path / "again"
    assert main([str(spec), "-o", str(again), "-q"]) == 0        # same spec and seeds → same numbers
    assert json.loads((again / "results.json").read_text())["ranking"] == res["ranking"]


def test_missing_engine_says_how_to_make_it_and_runs_the_quick_mode(tmp_path, capsys, monkeypatch):
    import glsim.workflows.design.cli as cli
    monkeypatch.setattr(cli, "make_engine", lambda name: Pyvale2D(python=tmp_path / "absent" / "python"))
    spec = write_spec(tmp_path / "spec.toml", plate_scene(size=(256, 256)), engine="pyvale2d",
                      dic={"subset_size": [21]}, rank={"by": "noise_floor_px"})
    assert main([str(spec), "-o", str(tmp_path / "out"), "-q"]) == 0
    err = capsys.readouterr().err
    assert "make .venv-verify/.pyvale-installed" in err and "quick mode only" in err
    assert json.loads((tmp_path / "out" / "results.json").read_text())["engine"] == "quick"


def _chromium():
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.process
def test_report_opens_in_headless_chromium(tmp_path):
    """The self-contained report in a real browser: its ranking table and every inline figure
    are in the page Chromium built, and the page it draws is not blank."""
    if _chromium() is None:
        pytest.skip("needs Debian's chromium (make test installs it)")
    spec = quick_spec(tmp_path)
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    url = (out / "report.html").resolve().as_uri()
    flags = ["--headless=new", "--no-sandbox", "--disable-gpu", f"--user-data-dir={tmp_path / 'chrome'}"]
    dom = subprocess.run([_chromium(), *flags, "--dump-dom", url], capture_output=True, text=True, timeout=120).stdout
    assert 'id="ranking"' in dom and dom.count("data:image/png;base64,") == 5
    shot = tmp_path / "shot.png"
    subprocess.run([_chromium(), *flags, f"--screenshot={shot}", "--window-size=1200,900", url],
                   capture_output=True, timeout=120)
    from PIL import Image
    pixels = np.asarray(Image.open(shot).convert("L"))
    assert pixels.std() > 10


# ---- the real engine ------------------------------------------------------------------------------
@pytest.mark.process
@pytest.mark.slow
@pytest.mark.engine
def test_pyvale_end_to_end_noise_floor_matches_the_quick_mode(tmp_path):
    """pyvale's 2-D DIC on a 2.5 px, −1 px rigid shift: every subset valid, the static pair's noise
    floor within 25 % of the quick mode's Cramér–Rao σ at the same centres, the error small."""
    if Pyvale2D().missing():
        pytest.skip(f"{Pyvale2D().missing()} (make test-engine makes it)")
    spec = write_spec(tmp_path / "spec.toml", plate_scene(size=(256, 256), shift_px=(2.5, -1.0), sigma=2.0,
                                                          bit_depth=8),
                      engine="pyvale2d", dic={"subset_size": [21], "subset_step": 12},
                      realisations={"noise_seeds": [1, 2]}, rank={"by": "p95_abs_error_px"})
    out = tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    r = json.loads((out / "results.json").read_text())["ranking"][0]
    assert r["valid_share"] > 0.95 and r["realisations"] == 2
    assert r["noise_floor_over_quick"] == pytest.approx(1.0, abs=0.25)
    assert r["p95_abs_error_px"] < 0.1
