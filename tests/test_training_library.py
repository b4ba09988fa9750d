"""glsim library's training mode end to end: bad [training] keys refused by key before anything
is written, resume after a deleted and a corrupted shard (only those written again) and after a
SIGKILL, --verify catching a flipped byte, nothing written outside -o, the same bytes on 1 and 2
workers and on Dask, and the StrainNet-like example's pairs."""
import shutil
from pathlib import Path

import numpy as np
import pytest

from glsim.workflows.library.cli import main as library_main
from glsim.workflows.training.spec import load_training

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TINY = EXAMPLES / "training_tiny.toml"
SHARDS = ("shard-000000.tar", "shard-000001.tar")


def _tree(d: Path) -> dict:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny") / "set"
    assert library_main([str(TINY), "-o", str(out), "--workers", "1", "-q"]) == 0
    return out


def _spec(tmp_path: Path, training: str, top: str = "") -> Path:
    text = TINY.read_text()
    head, rest = text.split("[training]", 1)
    body = rest.split("[vary]", 1)[1]
    spec = tmp_path / "spec.toml"
    spec.write_text(head + top + "\n[training]\n" + training + "\n[vary]" + body)
    return spec


@pytest.mark.parametrize("training, top, message", [
    ('formt = "webdataset"', "", "training.formt: unknown key — did you mean 'format'?"),
    ('format = "zarr"', "", "training.format: 'zarr' is not one of"),
    ("shard_bytes = 0", "", "training.shard_bytes: expected an integer of bytes"),
    ("step = 0", "", "training.step: expected a load step ≥ 1"),
    ("step = 2", "", "training.step: step 2 does not exist (the specimen has steps 0…1)"),
    ('cameras = ["cam9"]', "", "training.cameras: no camera named 'cam9'"),
    ("crop = [65, 8]", "", "training.crop: [65, 8] is larger than camera cam0's 64×64 px"),
    ("crop = [0, 8]", "", "training.crop: expected [width, height]"),
    ('labels = ["flux"]', "", "training.labels: 'flux' is not a label"),
    ('labels = ["disparity_ref"]', "", "training.labels: 'disparity_ref' needs two cameras"),
    ('image_dtype = "float32"', "", "training.image_dtype: 'float32' is not one of"),
    ('image_format = "jpg"', "", "training.image_format: 'jpg' is not one of"),
    ("", "steps = [0, 1]\n", "steps: is a library key, not used with [training]"),
])
def test_bad_training_keys_are_refused_by_key_with_exit_2_and_nothing_written(tmp_path, capsys, training, top,
                                                                                message):
    spec = _spec(tmp_path, training, top)
    before = _tree(tmp_path)
    assert library_main([str(spec), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert message in err and "—" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists() and _tree(tmp_path) == before


def test_uint8_images_of_a_12_bit_camera_are_refused_naming_the_fix(tmp_path, capsys):
    spec = _spec(tmp_path, 'image_dtype = "uint8"')
    spec.write_text(spec.read_text().replace("bit_depth = 8", "bit_depth = 12"))
    assert library_main([str(spec), "-o", str(tmp_path / "out")]) == 2
    assert "training.image_dtype: uint8 cannot hold camera cam0's 12-bit grey levels" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_resume_writes_a_deleted_and_a_corrupted_shard_again_and_keeps_the_other(tiny, tmp_path, capsys):
    out = tmp_path / "set"
    shutil.copytree(tiny, out)
    whole = _tree(tiny)
    (out / SHARDS[0]).unlink()
    kept = (out / SHARDS[1]).stat()
    assert library_main([str(out), "-q"]) == 0
    assert "1 shards written (2 pairs" in capsys.readouterr().out
    assert _tree(out) == whole
    assert (out / SHARDS[1]).stat().st_ino == kept.st_ino and (out / SHARDS[1]).stat().st_mtime_ns == kept.st_mtime_ns

    data = bytearray((out / SHARDS[1]).read_bytes())
    data[700] ^= 0x01                                    # inside the first member's bytes
    (out / SHARDS[1]).write_bytes(bytes(data))
    kept = (out / SHARDS[0]).stat()
    assert library_main([str(out), "--verify"]) == 1
    text = capsys.readouterr().out
    assert f"bad: {SHARDS[1]}: SHA-256 differs" in text and "1 shards good, 1 problems" in text
    assert library_main([str(TINY), "-o", str(out), "-q"]) == 0        # the spec again: the same set, resumed
    assert _tree(out) == whole and (out / SHARDS[0]).stat().st_ino == kept.st_ino
    assert library_main([str(out), "--verify"]) == 0
    assert "2 shards good, 0 problems" in capsys.readouterr().out


def test_another_spec_is_refused_without_force_and_nothing_is_written_outside_o(tiny, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "set"
    shutil.copytree(tiny, out)
    spec = _spec(tmp_path, "step = 1\ncrop = [32, 32]")
    before = _tree(tmp_path)
    assert library_main([str(spec), "-o", str(out), "-q"]) == 2
    assert "holds a training set of another spec" in capsys.readouterr().err and _tree(tmp_path) == before
    assert library_main([str(spec), "-o", str(out), "-q", "--force"]) == 0
    after = _tree(tmp_path)
    assert {k for k in after if not k.startswith("set/")} == {k for k in before if not k.startswith("set/")}
    # one shard of 1 GB now: the old set's second shard was removed with it
    assert sorted(p.name for p in out.iterdir()) == ["manifest.csv", "samples.csv", SHARDS[0], "training.json"]
    assert library_main([str(out), "--verify"]) == 0


def test_a_directory_holding_something_else_is_refused(tmp_path, capsys):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "notes.txt").write_text("mine")
    assert library_main([str(TINY), "-o", str(tmp_path / "out")]) == 2
    assert "holds no training set" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "out").iterdir()] == ["notes.txt"]


def test_dry_run_says_the_shards_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert library_main([str(TINY), "--dry-run"]) == 0
    text = capsys.readouterr().out
    assert "4 samples" in text and "2 per shard of 60 kB, 2 shards" in text and "nothing was written" in text
    assert "estimated: about" in text and "on one worker (measured here: v0000 in" in text
    assert list(tmp_path.iterdir()) == []


def test_samples_per_shard_follow_from_the_sample_size_as_the_spec_fixes_it():
    plan = load_training(TINY)
    assert plan.per_shard == plan.training.shard_bytes // plan.sample_bytes == 2
    assert [s.variants for s in plan.shards] == [("v0000", "v0001"), ("v0002", "v0003")]


@pytest.mark.process
def test_one_and_two_workers_give_the_same_bytes(tiny, tmp_path):
    assert library_main([str(TINY), "-o", str(tmp_path / "two"), "--workers", "2", "-q"]) == 0
    assert _tree(tmp_path / "two") == _tree(tiny)


@pytest.mark.process
def test_a_dask_cluster_gives_the_same_bytes(tiny, tmp_path):
    distributed = pytest.importorskip("distributed")
    from glsim.workflows.training import runner

    plan = load_training(TINY)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        summary = runner.run(plan, runner.stored_spec(plan), tmp_path / "dask", scheduler=client)
    assert summary.engine == "dask" and summary.written == 2 and not summary.failed
    assert _tree(tmp_path / "dask") == _tree(tiny)


def test_the_strainnet_like_example_gives_256_px_pairs_within_0_87_px(tmp_path):
    from glsim.workflows.library.spec import read_spec
    from glsim.workflows.training import runner
    from glsim.workflows.training.loader import samples
    from glsim.workflows.training.spec import expand_training

    spec, spec_dir = read_spec(EXAMPLES / "strainnet_like.toml")
    full = expand_training(spec, spec_dir, sample=6)
    assert full.library.n_variants == 363 * 60 and full.per_shard == 10**9 // full.sample_bytes == 756
    spec["vary"] = {"speckle": {"seed": [5]}, "specimen": {"field": {"seed": [0, 1, 2]}}}   # 3 of its pairs
    plan = expand_training(spec, spec_dir)
    assert runner.run(plan, runner.stored_spec(plan), tmp_path / "set", workers=1).samples == 3
    got = list(samples(tmp_path / "set" / "shard-000000.tar"))
    assert [s["json"]["seeds"] for s in got] == [{"speckle.seed": 5, "specimen.field.seed": k} for k in range(3)]
    for s in got:
        assert s["cam0_ref"].shape == (256, 256) and s["cam0_ref"].dtype == np.uint8
        for name in ("flow0", "forward0"):
            valid = s["mask_" + name].astype(bool)
            assert valid.mean() > 0.99 and 0.01 < np.abs(s[name][valid]).max() <= 0.87 + 1e-4, name


def test_a_damaged_training_json_naming_a_shard_outside_is_refused(tiny, tmp_path, capsys):
    out = tmp_path / "set"
    shutil.copytree(tiny, out)
    info = out / "training.json"
    info.write_text(info.read_text().replace('"shard-000001.tar"', '"../shard-000001.tar"'))
    assert library_main([str(out), "--verify"]) == 2
    assert "holds no training set (no training.json, or a damaged one)" in capsys.readouterr().err


@pytest.mark.process
def test_a_killed_run_resumes_to_the_bytes_of_an_uninterrupted_one(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    spec = _spec(tmp_path, "shard_bytes = 30_000\nstep = 1\ncrop = [48, 40]\nlabels = [\"flow\", \"mask_flow\"]")
    spec.write_text(spec.read_text().replace("speckle.seed = [1, 2]", "speckle.seed = [1, 2, 3, 4, 5]")
                    .replace("specimen.field.seed = [10, 11]", "specimen.field.seed = [10, 11, 12, 13]"))
    assert library_main([str(spec), "-o", str(tmp_path / "whole"), "--workers", "1", "-q"]) == 0
    assert len(list((tmp_path / "whole").glob("shard-*.tar"))) == 20
    out = tmp_path / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "glsim.cli", "library", str(spec), "-o", str(out), "--workers", "1",
                             "-q"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while proc.poll() is None and len(list(out.glob("shard-*.tar"))) < 3 and time.monotonic() < deadline:
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert len(list(out.glob("shard-*.tar"))) < 20                 # killed before the end
    with pytest.warns(UserWarning, match="took over the lock of a glsim run that is no longer running"):
        assert library_main([str(out), "-q"]) == 0
    assert _tree(out) == _tree(tmp_path / "whole") and not list(out.glob(".*"))
