"""Uniform values by name, written to any program in that program's own types.

The same name can be a ``vec2`` in one program and an ``ivec2`` or ``dvec2`` in another, and a
driver keeps only the leading elements of an array that the program reads (``array_length``).
:class:`Uniforms` holds the values (numbers or arrays, row-major) and writes those a program
has, converted to its types, on every :meth:`~Uniforms.write`: programs are shared per context,
so a value left by another renderer must never carry over.
"""
from __future__ import annotations

import numpy as np

_SCALARS = {"f": "<f4", "d": "<f8", "i": "<i4", "I": "<u4", "?": "<i4"}   # moderngl Uniform.fmt → dtype


def _bytes(fmt: str, length: int, value) -> bytes:
    """``value`` as a uniform of moderngl type ``fmt`` and ``array_length`` ``length``: its
    leading length × components scalars."""
    per = int(fmt[:-1] or 1)
    a = np.asarray(value, dtype=_SCALARS[fmt[-1]]).ravel()
    return a[:per * max(1, length)].tobytes()


class Uniforms:
    """Values of uniforms by name; :meth:`write` sets those a program has (others are ignored)."""

    def __init__(self, values: dict):
        self.values = values

    def write(self, prog) -> None:
        for name, value in self.values.items():
            u = prog.get(name, None)
            if u is not None and hasattr(u, "fmt"):
                u.write(_bytes(u.fmt, u.array_length, value))


def set_uniform(prog, name: str, value) -> None:
    """``prog[name].value = value``."""
    prog[name].value = value
