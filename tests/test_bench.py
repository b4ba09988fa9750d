"""glsim bench: the quick accuracy benchmark runs end to end and writes a sane report."""
import json
import math

import pytest

from glsim.bench import accuracy, cli
from glsim.check import closed_forms

pytestmark = [pytest.mark.workflow, pytest.mark.tools]   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

SIZE = ("203", "154")  # a very small image: the whole quick run takes a few seconds on llvmpipe


def _numbers(record):
    for value in record.values():
        if isinstance(value, list):
            yield from (v for v in value if isinstance(v, (int, float)))
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            yield value


@pytest.mark.slow
@pytest.mark.gl
def test_quick_accuracy_report(tmp_path, capsys):
    rc = cli.main(["accuracy", "--quick", "--size", *SIZE, "--reps", "1", "--out", str(tmp_path)])
    assert rc == 0
    report = json.loads((tmp_path / "accuracy.json").read_text())
    assert (tmp_path / "accuracy.md").read_text() in capsys.readouterr().out
    records = report["records"]
    combos = accuracy.combinations(quick=True)
    assert len(records) == len(combos)
    assert {(r["backend"], r["mode"], r["interpolation"], r["spp"], r["precision"]) for r in records} == {
        (c.backend, c.mode, c.interpolation, c.spp, c.precision) for c in combos}
    for r in records:
        assert all(math.isfinite(x) for x in _numbers(r)), r
        assert r["reps"] >= 1 and r["seconds"] > 0
    exact = next(r for r in records if r["backend"] == "gl" and r["mode"] == "exact" and r["precision"] == "fp64")
    if exact["arithmetic"] == "fp64":
        assert exact["map_max_px"] < closed_forms.FLOAT64
    else:   # a driver without GL_ARB_gpu_shader_fp64: float32, no derived bound; still above the approximations
        approx = [r["map_max_px"] for r in records if r["backend"] == "gl" and r["mode"] in ("fast", "q4")]
        assert exact["map_max_px"] < min(approx), (exact["map_max_px"], approx)
    cpu_exact = next(r for r in records if r["backend"] == "cpu" and r["mode"] == "exact")
    assert cpu_exact["map_max_px"] == 0 and cpu_exact["grey_max"] == 0  # the reference itself
    assert [t["target"] for t in report["targets"]] and len(report["peer"]) == 3


@pytest.mark.slow
@pytest.mark.gl
def test_bench_effects_quick(tmp_path):
    assert cli.main(["effects", "--size", *SIZE, "--reps", "1", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "effects.json").read_text())
    rows = {(r["backend"], r["effects"]): r for r in report["records"]}
    assert set(rows) == {(b, e) for b in ("gl", "cpu") for e in ("none", "lighting", "optics", "noise", "all")}
    assert all(math.isfinite(r["seconds"]) and r["seconds"] > 0 for r in rows.values())
    # the stages that ran are the ones the variant asked for
    assert rows["gl", "none"]["stages"] == ["raster", "interpolate"] and "noise" in rows["gl", "noise"]["stages"]
    assert rows["cpu", "lighting"]["stages"] == ["raster", "interpolate", "light"]
    assert (tmp_path / "effects.md").read_text().startswith("# glsim effects benchmark")
    # depth of field: every scheme on the bulge and the hard scenes, against the oracle
    dof = {(r["scene"], r["kernel"], r["scheme"]): r for r in report["dof"]}
    assert set(dof) == {(s, k, v) for s in ("bulge", "outline", "hole", "steps", "threshold")
                        for k, v in (("gaussian", "separable"), ("gaussian", "hybrid"), ("gaussian", "gather"),
                                     ("gaussian", "expansion"), ("disk", "gather"))}
    assert all(r["max_error"] <= report["dof_goal"] for k, r in dof.items() if k[2] != "separable")
    assert dof["hole", "gaussian", "separable"]["max_error"] > report["dof_goal"]
    assert "## Depth of field" in (tmp_path / "effects.md").read_text()
    # motion over the exposure and the rolling shutter, GL within half a grey level of the oracle
    motion = {(r["backend"], r["effects"]): r for r in report["motion"]}
    assert set(motion) == {(b, m) for b in ("gl", "cpu") for m in ("exposure", "rolling", "rolling, PSF")}
    assert all(r["max_gl_vs_cpu"] <= 0.5 / 255 and r["seconds"] > 0 and r["base_seconds"] > 0 for r in motion.values())


def test_reduced_runs_never_overwrite_the_committed_results(tmp_path, capsys, monkeypatch):
    """A quick or reduced run aimed at bench/results is refused before anything runs; without
    --out it goes to build/bench. The targets table says what a reduced run did not measure."""
    committed = cli.RESULTS / "accuracy.json"
    before = committed.read_bytes() if committed.exists() else None
    assert cli.main(["accuracy", "--quick", "--out", str(cli.RESULTS)]) == 2
    err = capsys.readouterr().err
    assert "--out bench/results" in err and "build/bench" in err and "full size" in err
    assert cli.main(["effects", "--size", *SIZE, "--out", str(cli.RESULTS)]) == 2
    assert (committed.read_bytes() if committed.exists() else None) == before
    assert cli.results_dir(None, full=False, command="accuracy") == cli.SCRATCH
    assert cli.results_dir(None, full=True, command="accuracy") == cli.RESULTS
    report = {"size": [203, 154], "records": [
        {"backend": "gl", "mode": "exact", "precision": "fp64", "arithmetic": "fp64", "map_max_px": 1e-12,
         "interpolation": "linear", "spp": 1, "seconds": 0.01},
        {"backend": "gl", "mode": "fast", "precision": "fp64", "arithmetic": "fp32", "map_max_px": 0.1,
         "interpolation": "linear", "spp": 1, "seconds": 0.01}]}
    assert [accuracy._met(t) for t in accuracy.targets(report)] == ["yes", "not measured at 1624×1234"]


@pytest.mark.slow
def test_bench_quadratic_reduced(tmp_path, capsys):
    """`glsim bench quadratic` at a reduced size: every mode of both backends against the closed
    form (exact to rounding, fast's chord error falling with the piece count), written beside
    the run's machine; aimed at bench/results it is refused."""
    assert cli.main(["quadratic", "--size", "96", "80", "--out", str(cli.RESULTS)]) == 2
    assert "would overwrite the committed" in capsys.readouterr().err
    assert cli.main(["quadratic", "--size", "96", "80", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "quadratic.json").read_text())
    assert report["machine"]["gl"]["renderer"] and [m["kind"] for m in report["meshes"]] == ["quad8", "triangle6"]
    for m in report["meshes"]:
        rows = {(r["backend"], r["mode"], r["pieces"]): r for r in m["rows"]}
        for backend in ("cpu", "gl"):
            assert rows[backend, "exact", None]["map_max"] < 1e-9
        fast = [r["map_mean"] for k, r in sorted(rows.items(), key=lambda kv: kv[0][2] or 0)
                if k[:2] == ("gl", "fast")]
        assert fast == sorted(fast, reverse=True)
    assert "## quad8" in (tmp_path / "quadratic.md").read_text()


@pytest.mark.slow
@pytest.mark.gl
def test_bench_throughput_quick(tmp_path):
    """`glsim bench throughput --quick`: every mode at 1 and 4 spp, one at a time and pipelined,
    and pipelined in the other pixel stage, those images bit for bit the single ones; aimed at
    bench/results it is refused."""
    assert cli.main(["throughput", "--quick", "--out", str(cli.RESULTS)]) == 2
    assert cli.main(["throughput", "--quick", "--size", "96", "72", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "throughput.json").read_text())
    rows = report["rows"]
    assert [(r["mode"], r["spp"]) for r in rows] == [(m, s) for m in ("fast", "q4", "exact") for s in (1, 4)]
    assert all(r["same_bytes"] for r in rows)
    other = {"fragment": "compute", "compute": "fragment"}[report["stage"]]   # (llvmpipe: fragment; a GPU: compute)
    assert {r["other_stage"] for r in rows} == {other} and all(r["other_pairs_per_s"] > 0 for r in rows)
    assert all(r["pipelined_pairs_per_s"] > 0 and r["single_pairs_per_s"] > 0 and r["passes"] for r in rows)
    assert all(r["fresh_host_ms"] > 0 for r in rows)   # (timings: not tested)
    text = (tmp_path / "throughput.md").read_text()
    assert text.startswith("# glsim throughput benchmark") and report["machine"]["gl"]["renderer"] in text


@pytest.mark.gl
def test_bench_jacobian_quick(tmp_path):
    """`glsim bench jacobian --quick`: every row of ROWS, the Jacobian's shape per row (the
    lighting's holds the normals' 1-ring: more non-zeros than the plain render's; the linear
    camera effects' the same pattern), the table in the markdown; aimed at bench/results it is refused."""
    from glsim.bench import jacobian as jbm

    assert cli.main(["jacobian", "--quick", "--out", str(cli.RESULTS)]) == 2
    assert cli.main(["jacobian", "--size", "96", "72", "--reps", "1", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "jacobian.json").read_text())
    rows = {(r["backend"], r["spp"], r["adds"]): r for r in report["rows"]}
    assert list(rows) == list(jbm.ROWS)
    plain = rows["gl", 1, "—"]
    assert rows["cpu", 1, "—"]["nnz"] == plain["nnz"] == rows["gl", 1, "vignetting, PRNU"]["nnz"] > 0
    assert rows["gl", 1, "lighting"]["nnz"] > 2 * plain["nnz"]
    assert all(r["render"] > 0 and r["jacobian"] > 0 for r in rows.values())   # (timings: not tested)
    assert jbm.table(report) in (tmp_path / "jacobian.md").read_text()
