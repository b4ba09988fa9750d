"""Training shards (glsim library with [training]): the tar layout — members, names, dtypes, fixed
headers —, the labels and images read back equal to pair_labels and the render of a fresh
Renderer bit for bit, the crop, and the loader's refusals."""
import csv
import io
import json
import tarfile
from pathlib import Path

import numpy as np
import pytest

from glsim.render import Renderer
from glsim.workflows.library.cli import main as library_main
from glsim.workflows.training.loader import ShardError, samples
from glsim.workflows.training.spec import load_training

pytestmark = pytest.mark.workflow   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

TINY = Path(__file__).resolve().parents[1] / "examples" / "training_tiny.toml"
KEYS = ("v0000", "v0001", "v0002", "v0003")
FIELDS = ("cam0_def.png", "cam0_ref.png", "flow0.npy", "json", "mask_flow0.npy")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """examples/training_tiny.toml written once in this process (1 worker): 4 samples, 2 shards."""
    out = tmp_path_factory.mktemp("tiny") / "set"
    assert library_main([str(TINY), "-o", str(out), "--workers", "1", "-q"]) == 0
    return out


def test_shards_hold_each_samples_members_sorted_with_fixed_headers(tiny):
    assert sorted(p.name for p in tiny.iterdir()) == ["manifest.csv", "samples.csv", "shard-000000.tar",
                                                      "shard-000001.tar", "training.json"]
    for k, shard in enumerate(("shard-000000.tar", "shard-000001.tar")):
        with tarfile.open(tiny / shard) as tar:
            members = tar.getmembers()
        names = [m.name for m in members]
        assert names == [f"{key}.{f}" for key in KEYS[2 * k:2 * k + 2] for f in FIELDS]
        for m in members:
            assert (m.type, m.mode, m.mtime, m.uid, m.gid, m.uname, m.gname) == (tarfile.REGTYPE, 0o644, 0, 0, 0, "", "")
    with open(tiny / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["shard"], r["samples"]) for r in rows] == [("shard-000000.tar", "2"), ("shard-000001.tar", "2")]
    assert all(int(r["bytes"]) == (tiny / r["shard"]).stat().st_size for r in rows)
    with open(tiny / "samples.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [(r["variant"], r["shard"], json.loads(r["speckle.seed"])) for r in table] == [
        ("v0000", "shard-000000.tar", 1), ("v0001", "shard-000000.tar", 1),
        ("v0002", "shard-000001.tar", 2), ("v0003", "shard-000001.tar", 2)]


def test_the_loader_gives_arrays_of_the_crop_with_their_dtypes(tiny):
    got = [s for shard in ("shard-000000.tar", "shard-000001.tar") for s in samples(tiny / shard)]
    assert [s["__key__"] for s in got] == list(KEYS)
    for s in got:
        assert sorted(s) == sorted(["__key__", "cam0_def", "cam0_ref", "flow0", "json", "mask_flow0"])
        assert s["cam0_ref"].dtype == s["cam0_def"].dtype == np.uint8 and s["cam0_ref"].shape == (40, 48)
        assert s["flow0"].dtype == np.float32 and s["flow0"].shape[:2] == (40, 48)
        assert s["mask_flow0"].dtype == np.uint8 and s["mask_flow0"].shape == (40, 48)
        x0, y0, w, h = s["json"]["crop"]
        assert (w, h) == (48, 40) and 0 <= x0 <= 64 - 48 and 0 <= y0 <= 64 - 40
        assert s["json"]["variant"] == s["__key__"] and s["json"]["step"] == 1
        assert s["json"]["seeds"]["speckle.seed"] == s["json"]["params"]["speckle.seed"]
    assert len({tuple(s["json"]["crop"]) for s in got}) > 1          # placed per sample from the seed


def test_labels_and_images_read_back_equal_pair_labels_of_a_fresh_render_bit_for_bit(tiny):
    from glsim.workflows.training.labels import pair_labels

    plan = load_training(TINY)
    got = {s["__key__"]: s for shard in ("shard-000000.tar", "shard-000001.tar") for s in samples(tiny / shard)}
    for v in plan.library.variants:
        with Renderer(v.scene) as r:          # fresh: no reference, context or renderer shared with the run
            ref = r.render("cam0", 0, truth=True, quantize=True)
            dfm = r.render("cam0", 1, truth=True, quantize=True)
        labels = pair_labels(v.scene, 1, {"cam0": ref.truth}, {"cam0": dfm.truth})
        s = got[v.id]
        x0, y0, w, h = s["json"]["crop"]
        for name, want in (("cam0_ref", ref.image), ("cam0_def", dfm.image), ("flow0", labels["flow0"]),
                           ("mask_flow0", labels["mask_flow0"])):
            want = want[y0:y0 + h, x0:x0 + w]
            assert s[name].dtype == want.dtype and s[name].shape == want.shape, name
            assert s[name].tobytes() == np.ascontiguousarray(want).tobytes(), f"{v.id} {name}"


def _tar(path: Path, members) -> Path:
    with tarfile.open(path, "w") as tar:
        for name, data, kind in members:
            ti = tarfile.TarInfo(name)
            ti.type = kind
            ti.size = len(data) if kind == tarfile.REGTYPE else 0
            if kind == tarfile.SYMTYPE:
                ti.linkname = "/etc/passwd"
            tar.addfile(ti, io.BytesIO(data) if kind == tarfile.REGTYPE else None)
    return path


@pytest.mark.parametrize("name, kind, what", [
    ("../v0000.flow0.npy", tarfile.REGTYPE, "is not KEY.NAME.npy"),
    ("v0000.flow0.pickle", tarfile.REGTYPE, "is not KEY.NAME.npy"),
    ("v0000.flow0.npy", tarfile.SYMTYPE, "not a regular file")])
def test_the_loader_refuses_a_member_that_is_not_a_samples_naming_it(tmp_path, name, kind, what):
    path = _tar(tmp_path / "bad.tar", [(name, b"x", kind)])
    with pytest.raises(ShardError, match=what) as e:
        list(samples(path))
    assert name in str(e.value) and "bad.tar" in str(e.value)


def test_the_loader_refuses_a_pickled_npy_and_a_cut_shard(tmp_path):
    buf = io.BytesIO()
    np.save(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ShardError, match="cannot be read as a shard"):
        list(samples(_tar(tmp_path / "p.tar", [("v0000.flow0.npy", buf.getvalue(), tarfile.REGTYPE)])))
    whole = _tar(tmp_path / "w.tar", [("v0000.flow0.npy", b"\x93NUMPY" + b"0" * 2000, tarfile.REGTYPE)]).read_bytes()
    (tmp_path / "cut.tar").write_bytes(whole[:1000])
    with pytest.raises(ShardError, match="cut.tar"):
        list(samples(tmp_path / "cut.tar"))


def test_the_example_loader_reads_every_pair(tiny):
    import runpy

    example = runpy.run_path(str(TINY.parent / "training_loader.py"))
    got = list(example["pairs"](tiny))
    assert len(got) == 4
    for ref, dfm, flow, mask in got:
        assert ref.dtype == dfm.dtype == np.float32 and ref.shape == (40, 48) and flow.shape == (40, 48, 2)
        assert mask.dtype == bool and mask.any() and np.abs(flow[mask]).max() <= 0.87 + 1e-6


def test_a_stereo_sample_holds_both_cameras_and_every_label_bit_for_bit(tmp_path):
    import tomli_w
    import tomllib

    from glsim.workflows.training.labels import pair_labels

    spec = tomllib.loads(TINY.read_text())
    cam1 = {**spec["scene"]["cameras"][0], "name": "cam1",
            "pose": {"stereo": {"Tx": -30.0, "Ty": 0.0, "Tz": 1.5, "Theta": 0.0, "Phi": 5.7, "Psi": 0.0}}}
    spec["scene"]["cameras"].append(cam1)
    spec["training"] = {"shard_bytes": 10**9, "step": 1, "crop": [40, 36]}
    spec["vary"] = {"specimen": {"field": {"seed": [3]}}}
    (tmp_path / "stereo.toml").write_bytes(tomli_w.dumps(spec).encode())
    assert library_main([str(tmp_path / "stereo.toml"), "-o", str(tmp_path / "set"), "--workers", "1", "-q"]) == 0
    (s,) = samples(tmp_path / "set" / "shard-000000.tar")
    maps = [f"{k}{i}" for k in ("flow", "forward") for i in (0, 1)] + ["disparity_ref", "disparity_def", "uvw"]
    assert sorted(s) == sorted(["__key__", "json", *(f"cam{i}_{t}" for i in (0, 1) for t in ("ref", "def")),
                                *maps, *(f"mask_{k}" for k in maps)])
    assert s["json"]["cameras"] == {"cam0": "cam0", "cam1": "cam1"}
    plan = load_training(tmp_path / "stereo.toml")
    scene = plan.library.variants[0].scene
    with Renderer(scene) as r:
        res = {(c, k): r.render(c, k, truth=True, quantize=True) for c in ("cam0", "cam1") for k in (0, 1)}
    labels = pair_labels(scene, 1, {c: res[c, 0].truth for c in ("cam0", "cam1")},
                         {c: res[c, 1].truth for c in ("cam0", "cam1")})
    x0, y0, w, h = s["json"]["crop"]
    want = {**labels, **{f"cam{i}_{t}": res[c, k].image for i, c in enumerate(("cam0", "cam1"))
                         for k, t in ((0, "ref"), (1, "def"))}}
    for name, a in want.items():
        a = np.ascontiguousarray(a[y0:y0 + h, x0:x0 + w])
        assert s[name].dtype == a.dtype and s[name].shape == a.shape and s[name].tobytes() == a.tobytes(), name
    assert s["mask_disparity_ref"].mean() > 0.9 and np.all(np.abs(s["disparity_ref"][s["mask_disparity_ref"] > 0]) < 20)


def test_the_loader_refuses_a_member_larger_than_its_bound_before_reading_it(tmp_path, monkeypatch):
    from glsim.workflows.training import loader

    monkeypatch.setattr(loader, "MAX_MEMBER", 100)
    path = _tar(tmp_path / "big.tar", [("v0000.flow0.npy", b"\x00" * 101, tarfile.REGTYPE)])
    with pytest.raises(ShardError, match=r"'v0000.flow0.npy' holds 101 bytes, more than 100"):
        list(samples(path))


def test_the_loader_refuses_a_member_past_the_memory_this_process_may_use(tmp_path, monkeypatch):
    """A member declaring more than half the process's memory budget (its bytes and the decoded
    array) is refused from its header, before it is read (the budget faked small here)."""
    from glsim.workflows.training import loader

    monkeypatch.setattr(loader, "memory_budget", lambda: 150)
    path = _tar(tmp_path / "big.tar", [("v0000.flow0.npy", b"\x00" * 101, tarfile.REGTYPE)])
    with pytest.raises(ShardError, match=r"more than half the 150 bytes this process may use"):
        list(samples(path))
