"""`glsim check` end to end: every check of the driver at hand passes and is reported with its
bound; a failing check makes the command exit 1."""
import json

import numpy as np
import pytest

from glsim.check import runner


@pytest.mark.workflow
@pytest.mark.slow
@pytest.mark.gl
def test_glsim_check_passes_here_and_writes_its_report(tmp_path, capsys):
    out = tmp_path / "check.json"
    assert runner.main(["--in-process", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["passed"] and [r["name"] for r in report["checks"]] == [c.name for c in runner.CHECKS]
    assert all(r["passed"] is not False and r["value"] <= r["bound"] for r in report["checks"] if r["value"] is not None)
    primitives = report["checks"][0]
    if primitives["value"] is not None:   # per primitive, each 0 here
        assert set(primitives["detail"]) >= {"split_double", "distort"} and not any(primitives["detail"].values())
    text = capsys.readouterr().out
    assert report["machine"]["gl"]["renderer"] in text.splitlines()[-1]     # the driver is named
    for r in report["checks"]:
        assert f"{r['name']}: " in text and f"≤ {r['bound']:.3g} {r['unit']}" in text
        if r["unit"] == "× bound" and r["value"] is not None:   # and the bound it is in units of
            assert runner.check_row(r) in text and f" {r['absolute_bound']['unit']})  (" in runner.check_row(r)


@pytest.mark.gl
def test_a_failing_check_fails_the_command(monkeypatch, tmp_path, capsys):
    wrong = runner.Check("a grey level off", 0.0, "grey levels", "a deliberately failing check", lambda c: 1.0)
    monkeypatch.setattr(runner, "CHECKS", (wrong,))
    assert runner.main(["--in-process", "--json", str(tmp_path / "c.json")]) == 1
    assert "FAIL  a grey level off: 1 ≤ 0 grey levels" in capsys.readouterr().out
    assert json.loads((tmp_path / "c.json").read_text())["passed"] is False


@pytest.mark.gl
def test_skipped_checks_are_not_run_and_are_named(monkeypatch, tmp_path, capsys):
    """--skip TEXT leaves out the checks whose name holds it (a driver that cannot build their
    programs); the report names them, the README's table marks them "not run"; a TEXT that
    matches no check is refused with the list of names, before anything runs."""
    from tools.docs.bench import check_drivers

    ran = []
    checks = tuple(runner.Check(n, 1.0, "units", "test", lambda c, n=n: ran.append(n) or 0.5) for n in ("alpha one", "beta two"))
    monkeypatch.setattr(runner, "CHECKS", checks)
    with pytest.raises(SystemExit):
        runner.main(["--skip", "gamma"])
    assert "--skip 'gamma' matches no check's name; the checks are: alpha one; beta two" in capsys.readouterr().err
    assert ran == []
    assert runner.main(["--in-process", "--skip", "beta", "--json", str(tmp_path / "c.json")]) == 0
    report = json.loads((tmp_path / "c.json").read_text())
    assert ran == ["alpha one"] and report["skipped"] == ["beta two"] and [r["name"] for r in report["checks"]] == ["alpha one"]
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "not run (--skip beta): beta two"            # said before the run
    assert out.splitlines()[-1].endswith("all passed in " + f"{report['seconds']} s; not run (--skip beta): beta two")
    full = dict(report, checks=report["checks"] + [dict(report["checks"][0], name="beta two")])
    assert check_drivers(full, report).splitlines()[-1] == "| beta two | 1.0 units | 0.50 ✓ | not run |"


_CRASHING = """
import os, signal, sys
from glsim.check import runner
def crash(c):
    os.kill(os.getpid(), signal.SIGSEGV)
def fail(c):
    raise RuntimeError("a bug in the check")
runner.CHECKS = tuple(runner.Check(n, 1.0, "units", "test", f) for n, f in (
    ("alpha", lambda c: 0.5), ("bravo", crash), ("charlie", lambda c: 0.25), ("delta", fail), ("echo", lambda c: 2.0)))
sys.exit(runner.main(["--json", sys.argv[1]]))
"""


@pytest.mark.process
@pytest.mark.gl
def test_a_driver_crash_in_one_check_still_gives_the_whole_report(tmp_path):
    """By default each check runs in a child process: a check that kills it (as a driver's
    segfault would) or raises is reported failed with how its process ended, and the checks
    after it still run in a new child; the command exits 1 with every row in the report."""
    import subprocess
    import sys

    out = tmp_path / "c.json"
    r = subprocess.run([sys.executable, "-c", _CRASHING, str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 1, r.stderr
    report = json.loads(out.read_text())
    rows = {x["name"]: x for x in report["checks"]}
    assert list(rows) == ["alpha", "bravo", "charlie", "delta", "echo"] and not report["passed"]
    assert [rows[n]["passed"] for n in rows] == [True, False, True, False, False]
    assert rows["bravo"]["value"] is None and rows["bravo"]["detail"] == {"crashed": "the process was killed by SIGSEGV"}
    assert rows["delta"]["detail"]["crashed"].startswith("an error ended the process (exit status 1")
    assert "RuntimeError: a bug in the check" in r.stderr and report["machine"]["gl"]["renderer"]
    assert "FAIL  bravo: – ≤ 1 units" in r.stdout and "crashed: the process was killed by SIGSEGV" in r.stdout
    assert "pass  alpha: 0.5 ≤ 1 units" in r.stdout and "pass  charlie: 0.25 ≤ 1 units" in r.stdout   # (the children's)
    from tools.docs.bench import check_drivers
    assert "| bravo | 1.0 units | crashed **✗** |" in check_drivers(report)


@pytest.mark.gl
def test_a_relative_checks_row_prints_its_absolute_bound(gl_ctx):
    """A check in units of a derived bound prints that bound beside it: one value, or the range
    of a per-pixel bound over the pixels compared."""
    def run(c):
        c.bound(np.array([[2e-5, 4e-5], [9.0, 3e-5]]), np.array([[True, True], [False, True]]), "px")
        c.bound(1e-9, np.ones((2, 2), bool), "px")
        return 0.5
    report = runner.run_checks(checks=(runner.Check("ranged", 1, "× bound", "test", run),
                                      runner.Check("plain", 0, "px off", "test", lambda c: 0.0)),
                              ctx=gl_ctx, progress=lambda line: None)
    ranged, plain = report["checks"]
    assert ranged["absolute_bound"] == {"min": 1e-9, "max": 4e-5, "unit": "px"} and "absolute_bound" not in plain
    assert "0.5 ≤ 1 × bound (bound 1e-09 … 4e-05 px)  (" in runner.check_row(ranged)
    assert "0 ≤ 0 px off  (" in runner.check_row(plain)


def test_a_failing_checks_detail_names_what_failed():
    """A check's detail (the float64 primitives' per-primitive counts) is printed where it fails,
    naming only what differed."""
    row = {"name": "float64 primitives", "bound": 0, "unit": "results differing in any bit", "value": 4096.0,
           "passed": False, "seconds": 0.4, "detail": {"split_double": 0, "distort": 4096}}
    assert runner.check_row(row).endswith("(0.4 s) — distort 4096")
    assert "—" not in runner.check_row(dict(row, value=0.0, passed=True, detail={"distort": 0}))
