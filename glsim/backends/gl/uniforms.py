"""Uniform values by name, written to any program in that program's own types.

The same name can be a ``vec2`` in one program and an ``ivec2`` or ``dvec2`` in another, and a
driver keeps only the leading elements of an array that the program reads (``array_length``).
:class:`Uniforms` holds the values (numbers or arrays, row-major) and makes the bytes for
each program the first time it is written there, so a frame's setup of a program it has set
up before is one driver call per uniform: no lookups, conversions or packing.
"""
from __future__ import annotations

import numpy as np

_SCALARS = {"f": "<f4", "d": "<f8", "i": "<i4", "I": "<u4", "?": "<i4"}   # moderngl Uniform.fmt → dtype


def _bytes(uniform, value) -> bytes:
    """``value`` as ``uniform``'s type: its leading array_length × components scalars."""
    fmt = uniform.fmt
    per = int(fmt[:-1] or 1)
    a = np.asarray(value, dtype=_SCALARS[fmt[-1]]).ravel()
    return a[:per * max(1, uniform.array_length)].tobytes()


class Uniforms:
    """Values of uniforms by name; :meth:`write` sets those a program has (others are ignored)."""

    def __init__(self, values: dict):
        self.values = values
        self._made: dict[int, tuple] = {}

    def write(self, prog) -> None:
        made = self._made.get(id(prog))
        if made is None or made[0] is not prog:
            writes = []
            for name, value in self.values.items():
                u = prog.get(name, None)
                if u is not None and hasattr(u, "fmt"):
                    writes.append((u.write, _bytes(u, value)))
            made = self._made[id(prog)] = (prog, writes)
        for write, data in made[1]:
            write(data)
