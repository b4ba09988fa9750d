"""Where a render's wall time goes, for the benchmarks (nothing here changes what is rendered).

``with driver_time() as t: ...`` adds up the time this thread spends waiting for the GPU in
glsim's read-backs (:meth:`glsim.backends.gl.readback.Pending.fetch`, which reports each wait
through :func:`waiting`) while the block runs; the rest of the block's wall time is the host's
own work — Python, numpy and the driver's command setup: the "CPU side" of a render that the
scaling and throughput benchmarks report. On llvmpipe the wait includes executing the shaders.

Pass by pass timing is the executor's own: :meth:`glsim.backends.gl.backend.GLBackend.pass_times`.
"""
from __future__ import annotations

import contextlib
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
