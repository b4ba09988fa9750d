"""Uniform values by name, written to any program in that program's own types.

The same name can be a ``vec2`` in one program and an ``ivec2`` or ``dvec2`` in another, and a
driver keeps only the leading elements of an array that the program reads (``array_length``).
:class:`Uniforms` holds the values (numbers or arrays, row-major) and makes their bytes once
per layout (the programs that have the same of its names in the same types share them); which
of its names a program has, and their types, is found once per program and set of names, for
every view after. A frame's setup of a program it has set up before is one driver call per
uniform: no lookups, conversions or packing.

:func:`set_uniform` sets one uniform that keeps its value across frames (a pass's layer, a
size) only when it changes: a program keeps its uniforms' values, and every
glsim write of such a name goes through it, so what it last wrote (kept in the program's
``extra``, as programs are shared per context) is what the program holds. A name is set by
one of the two ways in a program, never both (checked when either first sets it).
"""
from __future__ import annotations

import functools

import numpy as np

from glsim.backends.gl.replay import replayed

_SCALARS = {"f": "<f4", "d": "<f8", "i": "<i4", "I": "<u4", "?": "<i4"}   # moderngl Uniform.fmt → dtype


def _bytes(fmt: str, length: int, value) -> bytes:
    """``value`` as a uniform of moderngl type ``fmt`` and ``array_length`` ``length``: its
    leading length × components scalars."""
    per = int(fmt[:-1] or 1)
    a = np.asarray(value, dtype=_SCALARS[fmt[-1]]).ravel()
    return a[:per * max(1, length)].tobytes()


class Uniforms:
    """Values of uniforms by name; :meth:`write` sets those a program has (others are ignored).
    ``layouts``: where each program's uniforms of these names are kept (id(program) → (program,
    its uniforms, their types)), a dict shared by the Uniforms of the same names (a camera's
    views: a new view's values then make only their bytes)."""

    def __init__(self, values: dict, layouts: dict | None = None):
        self.values = values
        self._names = tuple(values)
        self._made = {} if layouts is None else layouts
        self._data: dict[tuple, tuple] = {}   # a layout's types → their bytes, shared by programs

    def write(self, prog) -> None:
        made = self._made.get(id(prog))
        if made is None or made[0] is not prog:
            made = self._made[id(prog)] = (prog, *_layout(prog, self._names))
        data = self._data.get(made[2])
        if data is None:
            data = self._data[made[2]] = tuple(_bytes(fmt, n, self.values[name]) for name, fmt, n in made[2])
        for u, d in zip(made[1], data):
            u.write(d)   # (looked up each time: glsim.backends.gl.timing counts it as a GL call)


def _layout(prog, names: tuple) -> tuple[tuple, tuple]:
    """The uniforms of ``names`` that ``prog`` has, in order, and their types (name, fmt,
    array_length): found once per program and set of names (a view's values are written to
    programs seen for other views; programs whose types agree share the values' bytes)."""
    layouts = _state(prog)["layouts"]
    hit = layouts.get(names)
    if hit is None:
        found = [(n, prog.get(n, None)) for n in names]
        found = [(n, u) for n, u in found if u is not None and hasattr(u, "fmt")]
        hit = layouts[names] = (tuple(u for _, u in found), tuple((n, u.fmt, u.array_length) for n, u in found))
        _written(prog, "values", names)
    return hit


def _state(prog) -> dict:
    """glsim's record in ``prog.extra``: "set" (name → the value :func:`set_uniform` last
    wrote), "values" (the names :class:`Uniforms` write) and "layouts" (:func:`_layout`)."""
    if prog.extra is None:
        prog.extra = {"set": {}, "values": set(), "layouts": {}}
    return prog.extra


def _written(prog, way: str, names) -> None:
    """Record that ``names`` are written ``way`` ("set" or "values") in ``prog``; a name written
    the other way too is a programming error (its recorded value would go stale)."""
    state = _state(prog)
    if way == "values" and state["values"].issuperset(names):
        return   # (each was checked when first recorded; set_uniform refuses them since)
    other = state["values" if way == "set" else "set"]
    clash = [n for n in names if n in other]
    if clash:
        raise RuntimeError(f"uniforms {clash} are set both through Uniforms and set_uniform in one program")
    if way == "values":
        state["values"].update(names)


def _set_again(prog, name: str, value):
    """What a replay runs for ``set_uniform(prog, name, value)``: for a number or a tuple, the
    comparison with the last write alone (the name's checks were made when it was recorded)."""
    if not isinstance(value, _SIMPLE):
        return functools.partial(set_uniform.__wrapped__, prog, name, value)
    return functools.partial(_set_if_changed, prog, name, value)


def _set_if_changed(prog, name: str, value) -> None:
    if prog.extra["set"].get(name, _UNSET) != value:
        prog[name].value = value
        prog.extra["set"][name] = value


@replayed(again=_set_again)
def set_uniform(prog, name: str, value) -> None:
    """``prog[name].value = value`` unless glsim's last write of ``name`` there was ``value``
    (a number or a tuple of numbers; other values are always written)."""
    simple = isinstance(value, _SIMPLE)
    state = prog.extra
    if simple and state is not None and state["set"].get(name, _UNSET) == value:
        return
    _written(prog, "set", (name,))
    prog[name].value = value
    prog.extra["set"][name] = value if simple else _UNSET


_UNSET = object()
_SIMPLE = (int, float, tuple)   # values set_uniform compares with the last written
