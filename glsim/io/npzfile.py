""".npz files read without believing them: each wanted member's ``.npy`` header (shape, dtype)
is read from the zip first, and the arrays are allocated only if what they declare fits the
memory this process may use (:func:`glsim.limits.memory_budget`) and the caller's own check of
the shapes — a zip bomb or a header declaring 10⁹ rows is refused by name, never a MemoryError.
Used for a library's geometry files, ``glsim render --truth``'s ``*_truth.npz`` and the DIC
results ``glsim compare`` reads."""
from __future__ import annotations

import io
import math
import struct
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from glsim.errors import GlsimError
from glsim.limits import memory_budget

try:
    from lzma import LZMAError
except ImportError:        # (a Python built without lzma cannot read such members at all)
    LZMAError = OSError


class NpzError(GlsimError):
    """An .npz that cannot be read as asked (the message names the file, the member and why)."""


@dataclass(frozen=True)
class Member:
    """One array as its ``.npy`` header declares it."""
    name: str
    shape: tuple[int, ...]
    dtype: np.dtype
    nbytes: int


def _header(z: zipfile.ZipFile, name: str) -> tuple[Member, int]:
    """The member ``name``'s declared array and the length of its ``.npy`` header (bytes)."""
    with z.open(name + ".npy") as f:
        version = np.lib.format.read_magic(f)
        readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        if version not in readers:
            raise ValueError(f"{name}: .npy format version {version} (glsim reads 1.0 and 2.0)")
        shape, _, dtype = readers[version](f)     # (numpy bounds the header text itself: 10,000 bytes)
        return Member(name, tuple(shape), dtype, math.prod(shape) * dtype.itemsize), f.tell()


def read_npz(source: str | Path | bytes, names, optional=(), budget: int | None = None,
             check: Callable[[dict], str] | None = None, label: str | None = None) -> dict[str, np.ndarray]:
    """The arrays ``names`` (all required) and those of ``optional`` that are present, from the
    .npz ``source`` (a path, or its bytes), each refused (NpzError) before it is allocated if:
    missing, of an object dtype, its zip entry's size not what its header declares, the wanted
    arrays together over ``budget`` bytes (default: :func:`~glsim.limits.memory_budget`), or
    ``check(members)`` (name → :class:`Member`) names a problem. ``label``: the file's name in
    messages (default: the path)."""
    label = label or (str(source) if not isinstance(source, bytes) else "the .npz")
    budget = memory_budget() if budget is None else budget
    need = 0
    try:
        with zipfile.ZipFile(io.BytesIO(source) if isinstance(source, bytes) else source) as z:
            present = {n[:-4] for n in z.namelist() if n.endswith(".npy")}
            missing = [n for n in names if n not in present]
            if missing:
                raise NpzError(f"{label}: has no {', '.join(missing)} (it holds {', '.join(sorted(present)) or 'none'})")
            members = {}
            for name in [*names, *(n for n in optional if n in present)]:
                m, start = _header(z, name)
                if m.dtype.hasobject:
                    raise NpzError(f"{label}: {name} holds Python objects ({m.dtype}), not numbers")
                if z.getinfo(name + ".npy").file_size != start + m.nbytes:
                    raise NpzError(f"{label}: {name} is {z.getinfo(name + '.npy').file_size:,} bytes in the zip where "
                                   f"its header declares {m.dtype} {m.shape} ({start + m.nbytes:,} bytes)")
                members[name] = m
            need = sum(m.nbytes for m in members.values())
            if need > budget:
                big = max(members.values(), key=lambda m: m.nbytes)
                raise NpzError(f"{label}: its arrays declare {need / 2**30:.3g} GiB ({big.name}: {big.dtype} "
                               f"{big.shape}), more than the {budget / 2**30:.3g} GiB this process may use")
            problem = check(members) if check else ""
            if problem:
                raise NpzError(f"{label}: {problem}")
            arrays = {}
            for name in members:
                with z.open(name + ".npy") as f:
                    arrays[name] = np.lib.format.read_array(f, allow_pickle=False)
            return arrays
    except NpzError:
        raise
    except MemoryError:
        raise NpzError(f"{label}: its arrays ({need / 2**30:.3g} GiB) do not fit in the memory left") from None
    except (OSError, ValueError, EOFError, KeyError, RuntimeError, struct.error, zlib.error, LZMAError,
            zipfile.BadZipFile) as exc:
        raise NpzError(f"{label}: not a readable .npz ({type(exc).__name__}: {exc})") from None
