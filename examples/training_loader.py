"""Read a glsim training set back: every shard's samples as numpy arrays, and, where PyTorch is
installed (pip install 'glsim[torch]'), the same as a torch IterableDataset.

    glsim library examples/training_tiny.toml -o tiny-set
    python examples/training_loader.py tiny-set

The numpy path needs nothing beyond glsim (tarfile, numpy; PNG through imageio). The PyTorch
path is a sketch kept import-guarded: it is not exercised by glsim's tests.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from glsim.workflows.training.loader import samples, shards


def pairs(directory):
    """(reference image, deformed image, flow, mask) of camera 0 per sample, as float32 / bool."""
    for path in shards(directory):
        for s in samples(path):
            yield (s["cam0_ref"].astype(np.float32), s["cam0_def"].astype(np.float32),
                   s.get("flow0"), s.get("mask_flow0", np.ones(s["cam0_ref"].shape, np.uint8)).astype(bool))


try:
    import torch
    from torch.utils.data import IterableDataset, get_worker_info
except ImportError:          # the numpy path above needs no torch
    torch = None
else:
    class ShardDataset(IterableDataset):
        """A training set's samples; each DataLoader worker reads every n-th shard."""

        def __init__(self, directory):
            self.paths = shards(directory)

        def __iter__(self):
            info = get_worker_info()
            k, n = (info.id, info.num_workers) if info is not None else (0, 1)
            for path in self.paths[k::n]:
                for s in samples(path):
                    grey = np.stack([s["cam0_ref"], s["cam0_def"]]).astype(np.float32)
                    grey /= float(np.iinfo(s["cam0_ref"].dtype).max)
                    yield torch.from_numpy(grey), torch.from_numpy(np.moveaxis(s["flow0"], -1, 0).copy())


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
        print("torch batch:", [tuple(t.shape) for t in batch])


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tiny-set")
