"""`glsim check` end to end: every check of the driver at hand passes and is reported with its
bound; a failing check makes the command exit 1."""
import json

import pytest

from glsim.evaluation import check


@pytest.mark.gl
def test_glsim_check_passes_here_and_writes_its_report(tmp_path, capsys):
    out = tmp_path / "check.json"
    assert check.main(["--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["passed"] and [r["name"] for r in report["checks"]] == [c.name for c in check.CHECKS]
    assert all(r["passed"] is not False and r["value"] <= r["bound"] for r in report["checks"] if r["value"] is not None)
    primitives = report["checks"][0]
    if primitives["value"] is not None:   # per primitive, each 0 here
        assert set(primitives["detail"]) >= {"split_double", "distort"} and not any(primitives["detail"].values())
    text = capsys.readouterr().out
    assert report["machine"]["gl"]["renderer"] in text.splitlines()[-1]     # the driver is named
    for r in report["checks"]:
        assert f"{r['name']}: " in text and f"≤ {r['bound']:.3g} {r['unit']}" in text


@pytest.mark.gl
def test_a_failing_check_fails_the_command(monkeypatch, tmp_path, capsys):
    wrong = check.Check("a grey level off", 0.0, "grey levels", "a deliberately failing check", lambda c: 1.0)
    monkeypatch.setattr(check, "CHECKS", (wrong,))
    assert check.main(["--json", str(tmp_path / "c.json")]) == 1
    assert "FAIL  a grey level off: 1 ≤ 0 grey levels" in capsys.readouterr().out
    assert json.loads((tmp_path / "c.json").read_text())["passed"] is False


@pytest.mark.gl
def test_skipped_checks_are_not_run_and_are_named(monkeypatch, tmp_path, capsys):
    """--skip TEXT leaves out the checks whose name holds it (a driver that cannot build their
    programs); the report names them, the README's table marks them "not run"; a TEXT that
    matches no check is refused with the list of names, before anything runs."""
    from glsim.evaluation.docs_bench import check_drivers

    ran = []
    checks = tuple(check.Check(n, 1.0, "units", "test", lambda c, n=n: ran.append(n) or 0.5) for n in ("alpha one", "beta two"))
    monkeypatch.setattr(check, "CHECKS", checks)
    with pytest.raises(SystemExit):
        check.main(["--skip", "gamma"])
    assert "--skip 'gamma' matches no check's name; the checks are: alpha one; beta two" in capsys.readouterr().err
    assert ran == []
    assert check.main(["--skip", "beta", "--json", str(tmp_path / "c.json")]) == 0
    report = json.loads((tmp_path / "c.json").read_text())
    assert ran == ["alpha one"] and report["skipped"] == ["beta two"] and [r["name"] for r in report["checks"]] == ["alpha one"]
    assert "(1 not run: --skip)" in capsys.readouterr().out
    full = dict(report, checks=report["checks"] + [dict(report["checks"][0], name="beta two")])
    assert check_drivers(full, report).splitlines()[-1] == "| beta two | 1.0 units | 0.50 ✓ | not run |"


def test_a_failing_checks_detail_names_what_failed():
    """A check's detail (the float64 primitives' per-primitive counts) is printed where it fails,
    naming only what differed."""
    row = {"name": "float64 primitives", "bound": 0, "unit": "results differing in any bit", "value": 4096.0,
           "passed": False, "seconds": 0.4, "detail": {"split_double": 0, "distort": 4096}}
    assert check.check_row(row).endswith("(0.4 s) — distort 4096")
    assert "—" not in check.check_row(dict(row, value=0.0, passed=True, detail={"distort": 0}))
