"""How much of a render's wall time the host spends outside the GL driver, and where the
driver's time goes.

``with driver_time() as t: ...`` counts the seconds spent inside moderngl calls (and so in the
driver: submissions, dispatches, waits for read-backs) while the block runs; the rest of the
block's wall time is the host's own work, Python and numpy: the "CPU side" of a render that the
scaling benchmark reports (``glsim bench scaling``). On llvmpipe the driver also executes the
shaders; on a GPU most of that time is the wait for the read-back.

``with pass_times(ctx, name_of) as p: ...`` times each draw and dispatch in the block on its
own (``p``: pass name → seconds, summed over its calls), with the driver finished before
and after each, so that no pass hides behind another: a breakdown of one render, not its
pipelined wall time.
"""
from __future__ import annotations

import contextlib
import functools
import time


class DriverTime:
    seconds = 0.0
    calls = 0


def _classes():
    import moderngl

    return [getattr(moderngl, n) for n in ("Context", "Buffer", "Texture", "TextureArray", "Framebuffer",
                                              "VertexArray", "Program", "ComputeShader", "Renderbuffer")
            if hasattr(moderngl, n)]


@contextlib.contextmanager
def driver_time():
    """Patch moderngl's public methods for the block's duration to add their time to the
    yielded counter (calls nested in others count once)."""
    t = DriverTime()
    depth = [0]
    saved = []

    def wrap(fn):
        @functools.wraps(fn)
        def inner(*args, **kwargs):
            if depth[0]:
                return fn(*args, **kwargs)
            depth[0] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                t.seconds += time.perf_counter() - t0
                t.calls += 1
                depth[0] -= 1
        return inner

    for cls in _classes():
        for name, value in list(vars(cls).items()):
            if name.startswith("_") or not callable(value) or isinstance(value, (staticmethod, classmethod, type)):
                continue
            saved.append((cls, name, value))
            setattr(cls, name, wrap(value))
    try:
        yield t
    finally:
        for cls, name, value in saved:
            setattr(cls, name, value)


@contextlib.contextmanager
def pass_times(ctx, name_of):
    """Patch moderngl's draw and dispatch calls for the block's duration: ``ctx.finish()``
    before and after each, its time added to the yielded dict under ``name_of(program)``."""
    import moderngl

    seconds: dict[str, float] = {}

    def timed(fn, program_of):
        @functools.wraps(fn)
        def inner(self, *args, **kwargs):
            name = name_of(program_of(self))
            ctx.finish()
            t0 = time.perf_counter()
            out = fn(self, *args, **kwargs)
            ctx.finish()
            seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0
            return out
        return inner

    calls = [(moderngl.VertexArray, "render", lambda vao: vao.program),
             (moderngl.VertexArray, "render_indirect", lambda vao: vao.program),   # (drawn where pass 1 said)
             (moderngl.ComputeShader, "run", lambda c: c)]
    saved = [(cls, name, getattr(cls, name)) for cls, name, _ in calls]
    for cls, name, program_of in calls:
        setattr(cls, name, timed(getattr(cls, name), program_of))
    try:
        yield seconds
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)
