"""Where a render's wall time goes, for the benchmarks (nothing here changes what is rendered).

``with driver_time() as t: ...`` adds up the time this thread spends waiting for the GPU in
glsim's read-backs (:meth:`glsim.backends.gl.readback.Pending.fetch`, which reports each wait
through :func:`waiting`) while the block runs; the rest of the block's wall time is the host's
own work — Python, numpy and the driver's command setup: the "CPU side" of a render that the
scaling and throughput benchmarks report. On llvmpipe the wait includes executing the shaders.

``with pass_times(ctx, name_of) as p: ...`` times each draw and dispatch in the block on its
own (``p``: pass name → seconds, summed over its calls), with the driver finished before
and after each, so that no pass hides behind another: a breakdown of one render, not its
pipelined wall time.
"""
from __future__ import annotations

import contextlib
import functools
import threading
import time


class DriverTime:
    """What :func:`driver_time` counted: ``seconds`` (wall) and ``cpu_seconds`` (this thread's
    CPU, :func:`time.thread_time`) spent waiting for the GPU, and ``calls``: how many waits."""

    def __init__(self):
        self.seconds = 0.0
        self.cpu_seconds = 0.0
        self.calls = 0

    def host_seconds(self, wall: float, cpu: float) -> tuple[float, float]:
        """(wall, CPU) seconds of the host's own work in a block that took ``wall`` seconds and
        ``cpu`` of this thread's CPU seconds: the time outside the waits."""
        return wall - self.seconds, cpu - self.cpu_seconds


_counting = threading.local()   # .active: the DriverTime blocks of this thread in progress


@contextlib.contextmanager
def driver_time():
    """Add up this thread's waits for the GPU (:func:`waiting`) in the block (the yielded
    :class:`DriverTime`)."""
    t = DriverTime()
    active = _counting.__dict__.setdefault("active", [])
    active.append(t)
    try:
        yield t
    finally:
        active.remove(t)


@contextlib.contextmanager
def waiting():
    """A wait for the GPU (a read-back), added to every :func:`driver_time` block in progress."""
    active = getattr(_counting, "active", None)
    if not active:
        yield
        return
    t0, c0 = time.perf_counter(), time.thread_time()
    try:
        yield
    finally:
        wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
        for t in active:
            t.seconds += wall
            t.cpu_seconds += cpu
            t.calls += 1


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
             (moderngl.ComputeShader, "run", lambda c: c),
             (moderngl.ComputeShader, "run_indirect", lambda c: c)]   # (as many groups as pass 1 listed)
    saved = [(cls, name, getattr(cls, name)) for cls, name, _ in calls]
    for cls, name, program_of in calls:
        setattr(cls, name, timed(getattr(cls, name), program_of))
    try:
        yield seconds
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)
