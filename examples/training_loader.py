"""Read a glsim training set back: every shard's samples as numpy arrays and, where PyTorch is
installed (pip install 'glsim[torch]'), as a torch IterableDataset.

    glsim library examples/training_tiny.toml -o tiny-set
    python examples/training_loader.py tiny-set

The numpy path (``pairs``) needs nothing beyond glsim (tarfile, numpy; PNG through imageio).
``ShardDataset`` is tested with torch 2.13.0 by ``make test-torch`` (tests/test_training_torch.py:
each sample once per epoch with 0 and 2 DataLoader workers, tensors equal to the numpy loader's
arrays bit for bit, the shuffle's order fixed by its seed and epoch):

    ds = ShardDataset("tiny-set", shuffle=True, seed=0)
    loader = torch.utils.data.DataLoader(ds, batch_size=8, num_workers=2)
    for epoch in range(10):
        ds.set_epoch(epoch)                 # a new order each epoch, the same for the same seed
        for batch in loader:
            batch["cam0"]        # (B, 2, H, W) float32: reference, deformed; grey / (2^bit_depth − 1)
            batch["flow0"]       # (B, 2, H, W) float32 px, channels first (every label kept: flow1, uvw, …)
            batch["mask_flow0"]  # (B, H, W) bool
            batch["__key__"]     # the samples' variant ids
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from glsim.workflows.training.loader import samples, shards
from glsim.workflows.training.runner import read_info


def pairs(directory):
    """(reference image, deformed image, flow, mask) of camera 0 per sample, as float32 / bool."""
    for path in shards(directory):
        for s in samples(path):
            yield (s["cam0_ref"].astype(np.float32), s["cam0_def"].astype(np.float32),
                   s.get("flow0"), s.get("mask_flow0", np.ones(s["cam0_ref"].shape, np.uint8)).astype(bool))


def set_info(directory) -> dict:
    """The set's training.json, or an error naming the directory and the fix."""
    info = read_info(Path(directory))
    if info is None:
        raise ValueError(f"{directory}: no readable training.json — not a glsim training set; make one with "
                         f"glsim library SPEC -o {directory}")
    return info


def full_scale(info: dict, sample_json: dict, i: int) -> int:
    """Camera i's full-scale grey level, 2^bit_depth − 1 (glsim.io.images.quantize): the sample's
    own bit depth where [vary] sets it, else the base scene's. Not the image's dtype: a 12-bit
    camera's images are uint16 holding 0 … 4095, and image_dtype = "uint16" widens 8-bit grey
    levels without scaling them."""
    name = sample_json["cameras"][f"cam{i}"]
    tables = info["spec"]["scene"]["cameras"]
    names = [t.get("name", f"cam{j}") for j, t in enumerate(tables)]
    j = names.index(name)
    params = sample_json.get("params", {})
    bits = params.get(f"cameras.{name}.bit_depth", params.get(f"cameras.{j}.bit_depth", tables[j].get("bit_depth", 8)))
    return (1 << int(bits)) - 1


_IMAGE = re.compile(r"cam(?P<i>[0-9]+)_(?P<tag>ref|def)")   # (not disparity_ref, a label)


def arrays(s: dict, info: dict) -> dict:
    """One sample as the dataset gives it, in numpy: ``cam{i}`` (2, H, W) float32 reference and
    deformed grey / full scale, each label channels first (float32), each mask bool, ``__key__``."""
    out = {"__key__": s["__key__"]}
    for name, a in s.items():
        image = _IMAGE.fullmatch(name)
        if name in ("__key__", "json") or (image and image["tag"] == "def"):
            continue
        if image:
            grey = np.stack([a, s[f"cam{image['i']}_def"]]).astype(np.float32)
            grey /= np.float32(full_scale(info, s["json"], int(image["i"])))
            out[f"cam{image['i']}"] = grey
        elif name.startswith("mask_"):
            out[name] = a.astype(bool)
        else:                       # (H, W, k) maps → (k, H, W); a copy: np.load's arrays are read-only
            out[name] = np.moveaxis(a, -1, 0).copy() if a.ndim == 3 else a.copy()
    return out


def shuffled(items, size: int, rng: np.random.Generator):
    """``items`` through a shuffle buffer of ``size`` (WebDataset's way: a shard's samples need
    not fit in memory; a larger buffer mixes more)."""
    buf = []
    for x in items:
        buf.append(x)
        if len(buf) >= size:
            i = int(rng.integers(len(buf)))
            buf[i], buf[-1] = buf[-1], buf[i]
            yield buf.pop()
    for i in rng.permutation(len(buf)):
        yield buf[i]


try:
    import torch
    from torch.utils.data import IterableDataset, get_worker_info
except ImportError:          # the numpy path above needs no torch
    torch = None
else:
    class ShardDataset(IterableDataset):
        """A training set's samples as dicts of tensors (``arrays``: every camera and label of
        the sample). DataLoader worker k of n reads every n-th shard, so each sample comes once
        per epoch (give a set at least as many shards as workers, or some workers idle).

        ``shuffle=True``: the shards in an order drawn from (seed, epoch), the same in every
        worker, and each worker's samples through a buffer of ``buffer`` samples drawn from
        (seed, epoch, worker): call ``set_epoch(e)`` before each epoch. The order depends on the
        number of workers. The DataLoader copies the dataset into its workers when an epoch
        starts, so keep ``persistent_workers=False`` (the default) for the epoch to reach them.
        """

        def __init__(self, directory, shuffle: bool = False, seed: int = 0, buffer: int = 64):
            self.info = set_info(directory)
            self.paths = shards(directory)
            self.shuffle, self.seed, self.buffer, self.epoch = bool(shuffle), int(seed), max(1, int(buffer)), 0

        def set_epoch(self, epoch: int) -> None:
            self.epoch = int(epoch)

        def __iter__(self):
            info = get_worker_info()
            k, n = (info.id, info.num_workers) if info is not None else (0, 1)
            paths = list(self.paths)
            if self.shuffle:
                paths = [paths[i] for i in np.random.default_rng([self.seed, self.epoch]).permutation(len(paths))]
            stream = (arrays(s, self.info) for path in paths[k::n] for s in samples(path))
            if self.shuffle:
                stream = shuffled(stream, self.buffer, np.random.default_rng([self.seed, self.epoch, k]))
            for a in stream:
                yield {name: v if isinstance(v, str) else torch.from_numpy(v) for name, v in a.items()}


def main(directory: str) -> None:
    n = 0
    for ref, dfm, flow, mask in pairs(directory):
        n += 1
        if n == 1:
            print(f"images {ref.shape} {ref.dtype}, flow {flow.shape} {flow.dtype}, "
                  f"|flow| ≤ {np.abs(flow[mask]).max():.3f} px on {mask.mean():.0%} of the pixels")
    print(f"{n} samples in {len(shards(directory))} shards of {Path(directory)}")
    if torch is not None:
        batch = next(iter(torch.utils.data.DataLoader(ShardDataset(directory), batch_size=2)))
        print("torch batch:", {k: tuple(v.shape) for k, v in batch.items() if k != "__key__"})


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tiny-set")
