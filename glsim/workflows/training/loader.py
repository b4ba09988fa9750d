"""Reading a training set's shards back: numpy and the standard library's tarfile (PNG through
imageio, which glsim depends on). No WebDataset or PyTorch needed; ``examples/training_loader.py``
wraps this in a PyTorch IterableDataset when torch is installed.

    from glsim.workflows.training.loader import samples
    for s in samples("set/shard-000000.tar"):
        s["__key__"], s["cam0_ref"], s["cam0_def"], s["flow0"], s["json"]["params"]

A member's size is bounded before it is read (``MAX_MEMBER``), .npy files load without pickles,
and a member that is not a sample's (another name, a link, a directory) is refused by name.
"""
from __future__ import annotations

import io
import json
import re
import tarfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from glsim.errors import GlsimError
from glsim.limits import memory_budget

MAX_MEMBER = 1 << 34          # 16 GiB: a 16384² float32 label with 16 channels
_NAME = re.compile(r"(?P<key>[^./]+)\.(?P<field>[A-Za-z0-9_]+)\.(?P<ext>npy|png)|(?P<jkey>[^./]+)\.json")


class ShardError(GlsimError):
    """A shard that is not a training set's (the message names the shard, the member and the fix)."""


def _decode(name: str, ext: str, data: bytes):
    if ext == "npy":
        return np.load(io.BytesIO(data), allow_pickle=False)
    if ext == "png":
        import imageio.v3 as iio
        return iio.imread(data, extension=".png")
    return json.loads(data)


def samples(path: str | Path, decode: bool = True) -> Iterator[dict]:
    """The samples of the shard ``path`` in order: dicts of ``__key__`` (the variant id), one
    array per image and label (``cam0_ref``, ``flow0``, …) and ``json`` (the sample's values);
    ``decode=False``: the members' bytes instead of arrays."""
    path = Path(path)
    fix = "write the shard again: glsim library DIR --verify names the damaged ones, glsim library DIR rewrites them"
    current: dict | None = None
    try:
        with tarfile.open(path, mode="r|") as tar:
            for m in tar:
                if not m.isreg():
                    raise ShardError(f"{path}: member {m.name!r} is not a regular file — {fix}")
                match = _NAME.fullmatch(m.name)
                if match is None:
                    raise ShardError(f"{path}: member {m.name!r} is not KEY.NAME.npy, KEY.NAME.png or KEY.json — {fix}")
                if m.size > MAX_MEMBER:
                    raise ShardError(f"{path}: member {m.name!r} holds {m.size} bytes, more than {MAX_MEMBER} — {fix}")
                if 2 * m.size > memory_budget():     # (its bytes and the decoded array)
                    raise ShardError(f"{path}: member {m.name!r} holds {m.size} bytes, more than half the "
                                     f"{memory_budget()} bytes this process may use — read it on a machine with "
                                     "more memory, or write smaller samples (crop)")
                key = match["key"] or match["jkey"]
                field, ext = (match["field"], match["ext"]) if match["key"] else ("json", "json")
                if current is not None and current["__key__"] != key:
                    yield current
                    current = None
                if current is None:
                    current = {"__key__": key}
                data = tar.extractfile(m).read()
                current[field] = _decode(m.name, ext, data) if decode else data
    except (tarfile.TarError, EOFError, ValueError, OSError) as exc:
        raise ShardError(f"{path}: cannot be read as a shard ({type(exc).__name__}: {exc}) — {fix}") from None
    if current is not None:
        yield current


def shards(directory: str | Path) -> list[Path]:
    """A training set's shards in order (from its manifest.csv)."""
    from glsim.workflows.training.runner import read_manifest
    rows = read_manifest(Path(directory))
    return [Path(directory) / name for name in sorted(rows)]
