"""How much of a render's wall time the host spends outside the GL driver, and where the
driver's time goes.

``with driver_time() as t: ...`` counts the seconds spent inside moderngl calls (and so in the
driver: submissions, dispatches, waits for read-backs) while the block runs; the rest of the
block's wall time is the host's own work, Python and numpy: the "CPU side" of a render that the
scaling benchmark reports (``glsim bench scaling``). On llvmpipe the driver also executes the
shaders; on a GPU most of that time is the wait for the read-back.

``with host_opcodes() as n: ...`` counts the Python bytecode instructions the thread executes
in the block outside moderngl (``n[0]`` when it ends): the same host work as a number that does
not depend on the machine's speed or on what else runs on it.

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
    """What :func:`driver_time` counted: ``seconds`` (wall) and ``cpu_seconds`` (this thread's
    CPU, :func:`time.thread_time`) inside moderngl calls, ``calls`` of them, and ``overhead``:
    the host CPU seconds the counting itself costs per call (measured on a no-op when the block
    starts), which :meth:`host_seconds` takes off. Beside real driver calls the counting can
    cost more than on the no-op, so the host seconds are an upper bound (the throughput
    benchmark measures the difference)."""
    seconds = 0.0
    cpu_seconds = 0.0
    calls = 0
    overhead = 0.0

    def host_seconds(self, wall: float, cpu: float) -> tuple[float, float]:
        """(wall, CPU) seconds of the host's own work in a block that took ``wall`` seconds and
        ``cpu`` of this thread's CPU seconds: the wall time outside the driver (on llvmpipe
        including the waits for a core its render threads hold) and the CPU time outside it."""
        counting = self.calls * self.overhead
        return wall - self.seconds - counting, cpu - self.cpu_seconds - counting


def _classes():
    import moderngl

    return [getattr(moderngl, n) for n in ("Context", "Buffer", "Texture", "TextureArray", "Framebuffer",
                                              "VertexArray", "Program", "ComputeShader", "Renderbuffer", "Uniform")
            if hasattr(moderngl, n)]


def _counter(t: DriverTime):
    depth = [0]

    def wrap(fn):
        @functools.wraps(fn)
        def inner(*args, **kwargs):
            if depth[0]:
                return fn(*args, **kwargs)
            depth[0] += 1
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                t.seconds += time.perf_counter() - t0
                t.cpu_seconds += time.thread_time() - c0
                t.calls += 1
                depth[0] -= 1
        return inner
    return wrap


@functools.cache
def noop_cost(n: int = 2000) -> tuple[float, float]:
    """CPU seconds per call that counting adds to a no-op: (outside the counted interval — the
    wrapper's own Python, which :meth:`DriverTime.host_seconds` takes off — and in all), from
    ``n`` calls of a no-op counted and not (measured once per process)."""
    def noop():
        return None
    probe = DriverTime()
    counted = _counter(probe)(noop)
    c0 = time.thread_time()
    for _ in range(n):
        noop()
    c1 = time.thread_time()
    for _ in range(n):
        counted()
    c2 = time.thread_time()
    total = max(0.0, ((c2 - c1) - (c1 - c0)) / n)
    return max(0.0, total - probe.cpu_seconds / n), total


# moderngl's own bookkeeping, no driver call: every moderngl object's finalizer reads gc_mode,
# so a garbage collection inside a counted block would count one call per object it frees
_BOOKKEEPING = {"gc_mode", "objects"}


@contextlib.contextmanager
def patched(wrap):
    """Replace moderngl's public methods and property accessors (state such as ``viewport`` and
    ``depth_func``, a uniform's ``value``: their setters call the driver) by ``wrap(fn, cls,
    name, kind)`` (``kind``: "call", "get" or "set") for the block's duration."""
    saved = []
    for cls in _classes():
        for name, value in list(vars(cls).items()):
            if name.startswith("_") or name in _BOOKKEEPING:
                continue
            if isinstance(value, property):
                wrapped = property(value.fget and wrap(value.fget, cls, name, "get"),
                                   value.fset and wrap(value.fset, cls, name, "set"), value.fdel)
            elif callable(value) and not isinstance(value, (staticmethod, classmethod, type)):
                wrapped = wrap(value, cls, name, "call")
            else:
                continue
            saved.append((cls, name, value))
            setattr(cls, name, wrapped)
    try:
        yield
    finally:
        for cls, name, value in reversed(saved):
            setattr(cls, name, value)


@contextlib.contextmanager
def driver_time():
    """Count moderngl's public methods and properties (:func:`patched`; they call the driver,
    which may flush its queue there) for the block's duration: their time is added to the
    yielded counter (calls nested in others count once)."""
    t = DriverTime()
    t.overhead = noop_cost()[0]
    count = _counter(t)
    with patched(lambda fn, cls, name, kind: count(fn)):
        yield t


@contextlib.contextmanager
def host_opcodes():
    """Count the bytecode instructions this thread executes in the block, in every Python frame
    started or resumed in it but moderngl's (its wrappers are driver calls here, as for
    :func:`driver_time`); yields a one-item list that holds the count when the block ends.
    Sees every instruction: tens of times slower, for a few frames only. Python 3.11:
    ``sys.settrace`` opcode events; 3.12 on: ``sys.monitoring`` INSTRUCTION events (there the
    opcode events of ``settrace`` miss a process's first block, on 3.13 every block). The
    counts are comparable within one Python version only."""
    import sys

    count = [0]
    with (_instructions if sys.version_info >= (3, 12) else _opcodes)(count):
        yield count


@contextlib.contextmanager
def _opcodes(count: list):
    import sys

    def local(frame, event, arg):
        if event == "opcode":
            count[0] += 1
        return local

    def calls(frame, event, arg):
        if "moderngl" in frame.f_code.co_filename:
            return None
        frame.f_trace_opcodes = True
        return local

    before = sys.gettrace()
    sys.settrace(calls)
    try:
        yield
    finally:
        sys.settrace(before)


@contextlib.contextmanager
def _instructions(count: list):
    import sys

    mon = sys.monitoring
    events = mon.events
    tool = next((t for t in range(6) if mon.get_tool(t) is None), None)
    if tool is None:
        raise RuntimeError("host_opcodes: all six sys.monitoring tool ids are taken")
    seen: set = set()

    def start(code, offset):
        if code not in seen and "moderngl" not in code.co_filename:
            seen.add(code)
            mon.set_local_events(tool, code, events.INSTRUCTION)

    def step(code, offset):
        count[0] += 1

    mon.use_tool_id(tool, "glsim host_opcodes")
    try:
        mon.register_callback(tool, events.INSTRUCTION, step)
        mon.register_callback(tool, events.PY_START, start)
        mon.register_callback(tool, events.PY_RESUME, start)
        mon.set_events(tool, events.PY_START | events.PY_RESUME)
        yield
    finally:
        mon.set_events(tool, 0)
        for code in seen:
            mon.set_local_events(tool, code, 0)
        for event in (events.INSTRUCTION, events.PY_START, events.PY_RESUME):
            mon.register_callback(tool, event, None)
        mon.free_tool_id(tool)


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
