"""glsim design's row cache is trusted only as far as row.json vouches for it: a result.npz whose
size or SHA-256 is not the one recorded (a flipped byte, a truncated or swapped file), a row.json
too large to be one glsim wrote, or one naming arrays the file lacks, makes that row computed
again — never a silently wrong number in the ranking."""
import json
import os

from glsim.workflows.design import run as design_run
from glsim.workflows.design.cli import main

from _design import plate_scene, write_spec


def _spec(tmp_path):
    return write_spec(tmp_path / "spec.toml", plate_scene(sigma=1.0, bit_depth=8), engine="quick",
                      dic={"subset_size": [15, 25], "subset_step": 12})


def _ranking(out):
    return json.loads((out / "results.json").read_text())["ranking"]


def _recomputed(monkeypatch):
    calls = []
    real = design_run.quick_row
    monkeypatch.setattr(design_run, "quick_row", lambda *a: calls.append(a) or real(*a))
    return calls


def test_a_damaged_row_is_computed_again_and_the_others_kept(tmp_path, monkeypatch):
    spec, out = _spec(tmp_path), tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    before = _ranking(out)
    rows = sorted((out / "rows").iterdir())
    assert len(rows) == 2
    flipped = rows[0] / "result.npz"
    data = bytearray(flipped.read_bytes())
    data[len(data) // 2] ^= 0x01                  # inside an array's bytes: np.load would read it
    flipped.write_bytes(bytes(data))
    calls = _recomputed(monkeypatch)
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert len(calls) == 1 and _ranking(out) == before
    # resumed again: nothing computed
    calls.clear()
    assert main([str(spec), "-o", str(out), "-q"]) == 0 and calls == []


def test_row_json_that_is_huge_or_names_missing_arrays_is_not_believed(tmp_path, monkeypatch):
    spec, out = _spec(tmp_path), tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    before = _ranking(out)
    a, b = sorted((out / "rows").iterdir())
    with open(a / "row.json", "r+b") as f:         # a sparse file past the bound: refused by its size
        f.truncate(design_run.ROW_META_BYTES + 1)
    meta = json.loads((b / "row.json").read_text())
    meta["arrays"] = meta["arrays"] + ["not_there"]
    (b / "row.json").write_text(json.dumps(meta))
    calls = _recomputed(monkeypatch)
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert len(calls) == 2 and _ranking(out) == before
    assert os.path.getsize(a / "row.json") < design_run.ROW_META_BYTES


def test_a_result_swapped_for_another_rows_is_caught(tmp_path, monkeypatch):
    """Both files are glsim's and well-formed, but a's result.npz is b's: a's row.json hash says no."""
    spec, out = _spec(tmp_path), tmp_path / "out"
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    before = _ranking(out)
    a, b = sorted((out / "rows").iterdir())
    (a / "result.npz").write_bytes((b / "result.npz").read_bytes())
    calls = _recomputed(monkeypatch)
    assert main([str(spec), "-o", str(out), "-q"]) == 0
    assert len(calls) == 1 and _ranking(out) == before
