"""The PyTorch path of examples/training_loader.py (make test-torch installs torch 2.13.0; without
torch this module skips, and under GLSIM_REQUIRE_TORCH=1 that skip fails): ShardDataset in a
DataLoader with 0 and 2 workers gives each sample of a set exactly once per epoch, its tensors
equal to the numpy loader's arrays bit for bit — images divided by the camera's full scale
2^bit_depth − 1 (checked apart from the PNG's or .npy's own dtype), labels channels first, masks
bool — for one and two cameras, and a shuffle whose order the seed and the epoch fix."""
import importlib.util
import io
import os
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

if os.environ.get("GLSIM_REQUIRE_TORCH") == "1":     # make test-torch: no torch is an error, not a skip
    import torch                                       # (a module's skip is a collection report,
else:                                                  # which conftest's hook on test reports misses)
    torch = pytest.importorskip("torch")

from glsim.workflows.library.cli import main as library_main      # noqa: E402
from glsim.workflows.training.loader import samples, shards     # noqa: E402

pytestmark = [pytest.mark.torch, pytest.mark.workflow]

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
STEREO = {"Tx": -30.0, "Ty": 0.0, "Tz": 1.5, "Theta": 0.0, "Phi": 5.7, "Psi": 0.0}


def _example():
    """examples/training_loader.py as a module (registered, so that its classes pickle by name)."""
    spec = importlib.util.spec_from_file_location("glsim_example_training_loader", EXAMPLES / "training_loader.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


EX = _example()


def _make(root: Path, name: str, edit) -> Path:
    """examples/training_tiny.toml with ``edit`` applied, written with one worker under ``root``."""
    import tomli_w

    spec = tomllib.loads((EXAMPLES / "training_tiny.toml").read_text())
    edit(spec)
    (root / f"{name}.toml").write_bytes(tomli_w.dumps(spec).encode())
    out = root / name
    assert library_main([str(root / f"{name}.toml"), "-o", str(out), "--workers", "1", "-q"]) == 0
    return out


def _five(spec):          # 5 samples at 2 a shard: 3 shards, the last holding one
    spec["vary"] = {"speckle": {"seed": [1]}, "specimen": {"field": {"seed": [10, 11, 12, 13, 14]}}}


def _stereo_12_10(spec):  # camera 0 12-bit, camera 1 10-bit: uint16 PNGs below their dtype's full scale
    _five(spec)
    cam0 = spec["scene"]["cameras"][0]
    cam0["bit_depth"] = 12
    spec["scene"]["cameras"].append({**cam0, "name": "cam1", "bit_depth": 10, "pose": {"stereo": STEREO}})
    spec["training"]["shard_bytes"] = 10**9


def _widened_npy(spec):   # an 8-bit camera written as uint16 .npy: grey levels widened, not scaled
    _five(spec)
    spec["training"].update(image_dtype="uint16", image_format="npy")


def _varied_depth(spec):  # the bit depth varied per sample
    spec["vary"] = {"cameras": {"cam0": {"bit_depth": [8, 12]}}, "specimen": {"field": {"seed": [10]}}}


SHARDS = {"five": 3, "stereo": 1, "widened": 5}     # (uint16 doubles a sample: 1 a shard)
CASES = {"five": (_five, {"cam0": 8}), "stereo": (_stereo_12_10, {"cam0": 12, "cam1": 10}),
         "widened": (_widened_npy, {"cam0": 8}), "varied": (_varied_depth, None)}


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    root = tmp_path_factory.mktemp("torch-sets")
    return {name: _make(root, name, edit) for name, (edit, _) in CASES.items()}


def _numpy_samples(directory) -> dict:
    """key → the numpy loader's sample, in the set's order."""
    return {s["__key__"]: s for path in shards(directory) for s in samples(path)}


def _stored_bits(directory, key: str, cam: str) -> int:
    """The bits per grey level a member stores, read from its own header: a PNG's IHDR bit depth,
    a .npy's dtype."""
    for path in shards(directory):
        for s in samples(path, decode=False):
            if s["__key__"] == key:
                data = s[f"{cam}_ref"]
                if data[:8] == b"\x89PNG\r\n\x1a\n":
                    assert data[12:16] == b"IHDR" and data[25] == 0        # grey, no alpha
                    return data[24]
                return np.lib.format.read_array(io.BytesIO(data)).dtype.itemsize * 8
    raise AssertionError(f"{key} not in {directory}")


def _expected(s: dict, scales: dict) -> dict:
    """A sample as ShardDataset should give it, from the numpy loader's arrays: each camera's
    reference and deformed grey / (2^bits − 1) as float32, labels channels first, masks bool."""
    want = {}
    for cam, bits in scales.items():
        full = np.float32((1 << bits) - 1)
        want[cam] = np.stack([s[f"{cam}_ref"].astype(np.float32) / full, s[f"{cam}_def"].astype(np.float32) / full])
    for name, a in s.items():
        if name.startswith("mask_"):
            want[name] = a != 0
        elif name.startswith(("flow", "forward", "disparity", "uvw")):
            want[name] = np.transpose(a, (2, 0, 1))
    return want


WORKERS = [0, pytest.param(2, marks=pytest.mark.process)]     # DataLoader worker processes


def _read(ds, workers: int) -> list[dict]:
    """Every sample the DataLoader gives (batches of 2 split back into samples), in order."""
    out = []
    for batch in torch.utils.data.DataLoader(ds, batch_size=2, num_workers=workers):
        for j, key in enumerate(batch["__key__"]):
            out.append({"__key__": key, **{k: v[j] for k, v in batch.items() if k != "__key__"}})
    return out


def _assert_equal(got: dict, want: dict):
    assert sorted(got) == sorted(["__key__", *want]), got["__key__"]
    for name, w in want.items():
        g = got[name].numpy()
        assert g.dtype == w.dtype and g.shape == w.shape, (got["__key__"], name, g.dtype, g.shape)
        assert g.tobytes() == np.ascontiguousarray(w).tobytes(), (got["__key__"], name)


@pytest.mark.parametrize("workers", WORKERS)
@pytest.mark.parametrize("case", ["five", "stereo", "widened"])
def test_each_sample_comes_once_equal_to_the_numpy_loaders_arrays_bit_for_bit(sets, case, workers):
    directory, scales = sets[case], CASES[case][1]
    ref = _numpy_samples(directory)
    assert list(ref) == [f"v{i:04d}" for i in range(5)] and len(shards(directory)) == SHARDS[case]
    got = _read(EX.ShardDataset(directory), workers)
    assert sorted(g["__key__"] for g in got) == list(ref)                  # each once, none missing
    if workers == 0:
        assert [g["__key__"] for g in got] == list(ref)                   # unshuffled: the set's order
    for g in got:
        s = ref[g["__key__"]]
        _assert_equal(g, _expected(s, scales))
        for cam, bits in scales.items():
            stored = _stored_bits(directory, g["__key__"], cam)
            assert stored == (8 if case == "five" else 16)
            assert s[f"{cam}_ref"].dtype == np.dtype(f"uint{stored}")
            grey = g[cam].numpy()
            assert 0 <= grey.min() and grey.max() <= 1
            # the camera's full scale, not the stored dtype's: 12- and 10-bit grey levels fill more
            # than 8 bits yet stay below 2^bits, and widened 8-bit ones stay below 256
            top = max(int(s[f"{cam}_ref"].max()), int(s[f"{cam}_def"].max()))
            assert top < (1 << bits) and (bits == 8 or top >= 256)
            assert grey.max() == np.float32(top) / np.float32((1 << bits) - 1)
    if case == "stereo":
        assert {"cam0", "cam1", "flow0", "flow1", "mask_flow0", "mask_flow1"} <= set(got[0])
        assert got[0]["cam0"].shape == (2, 40, 48) and got[0]["flow1"].shape == (2, 40, 48)
        assert got[0]["mask_flow1"].dtype == torch.bool


def test_a_bit_depth_varied_per_sample_scales_each_sample_by_its_own(sets):
    ref = _numpy_samples(sets["varied"])
    got = _read(EX.ShardDataset(sets["varied"]), 0)
    assert [g["__key__"] for g in got] == list(ref) == ["v0000", "v0001"]
    for g, bits in zip(got, (8, 12)):
        s = ref[g["__key__"]]
        assert s["json"]["params"] == {"cameras.cam0.bit_depth": bits, "specimen.field.seed": 10}
        _assert_equal(g, _expected(s, {"cam0": bits}))


def _order(ds, workers: int) -> list[str]:
    return [g["__key__"] for g in _read(ds, workers)]


@pytest.mark.parametrize("workers", WORKERS)
def test_the_shuffle_gives_each_sample_once_in_an_order_its_seed_and_epoch_fix(sets, workers):
    directory = sets["five"]
    ref = _numpy_samples(directory)
    ds = EX.ShardDataset(directory, shuffle=True, seed=3, buffer=2)
    orders = {}
    for epoch in (0, 1, 0):
        ds.set_epoch(epoch)                     # on the main process's copy: reaches the workers
        got = _read(ds, workers)
        assert sorted(g["__key__"] for g in got) == list(ref)
        for g in got:
            _assert_equal(g, _expected(ref[g["__key__"]], {"cam0": 8}))
        order = [g["__key__"] for g in got]
        assert orders.setdefault(epoch, order) == order          # epoch 0 again: the same order
    assert orders[0] != orders[1] and list(ref) not in (orders[0], orders[1])
    other = EX.ShardDataset(directory, shuffle=True, seed=4, buffer=2)
    assert _order(other, workers) != orders[0]


def test_a_directory_that_is_not_a_training_set_is_refused_by_name(tmp_path):
    with pytest.raises(ValueError, match="not a glsim training set") as e:
        EX.ShardDataset(tmp_path)
    assert str(tmp_path) in str(e.value) and "glsim library SPEC -o" in str(e.value)
