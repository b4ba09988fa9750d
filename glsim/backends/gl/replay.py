"""Deformation passes recorded once and replayed: a camera's view rendered again, or another
step's, issues the GL commands it issued before, without the Python that decided them.

For one camera, options, plan, supersampling, truth flag, lights, aperture and bit depth, the
deformation pass with the box filter and (where no image effect comes between) the GPU
quantisation (:meth:`GLBackend._deform`) issues the same commands for every view: the same
programs, targets, camera uniforms and draws, in the same order; only the step's buffers and
the view's own uniforms differ, and those go through calls marked view-dependent
(:class:`glsim.backends.gl.geometry.ViewSlot`). :class:`Frames` records a key's commands on
its second render (the first makes what the key needs: programs, buffers, targets, ray maps)
and replays them on the renders after it, so the images and truth are the same bit for bit.

A recording (:func:`recording`) keeps this thread's moderngl calls that change GL state
(RECORDED) and glsim's calls marked :func:`replayed`, which must run again as calls (a
uniform written only where it changes, an error check, what a view binds and writes); the
calls nested in those are theirs. It keeps two lists: what any view replays (the
view-dependent calls as calls) and what the recorded view replays (their GL calls in their
place: no Python of theirs). Anything else — a GL object made, released or read, an error
read — abandons the recording, and the pass runs as it would have; inside a view-dependent
call (a new step's upload) it leaves only the recorded view's list unusable. A record is
dropped when an object it names has been released since (an evicted cache entry): the next
render records again. Replays look their methods up on the object each time, so
:mod:`glsim.backends.gl.timing`'s counting and pass timing see them as they see the recorded
calls.
"""
from __future__ import annotations

import collections
import contextlib
import functools
import operator
import threading
import weakref

import numpy as np

from glsim.limits import keep

RECORDED = {   # moderngl class → its calls (methods, property setters) that change GL state
    "Buffer": {"bind_to_storage_buffer", "write"},
    "Texture": {"use", "bind_to_image"},
    "TextureArray": {"use", "bind_to_image"},
    "Framebuffer": {"use", "clear", "viewport", "depth_mask"},
    "Context": {"memory_barrier", "enable", "disable", "depth_func", "detect_framebuffer"},
    "Uniform": {"write"},
    "ComputeShader": {"run", "run_indirect"},
    "VertexArray": {"render", "render_indirect"},
}
_LOOKUPS = {("Program", "get"), ("ComputeShader", "get")}   # the host's own tables: not GL calls
_RELEASABLE = {"Buffer", "Texture", "TextureArray", "Framebuffer", "Renderbuffer", "VertexArray",
               "ComputeShader", "Program"}
_MGLO = operator.attrgetter("mglo")
_CALL = getattr(operator, "call", lambda f: f())   # (operator.call: Python 3.11 on)
MAX_FAILURES = 2   # abandoned recordings of a key before it is left to run as it is
FRAMES_KEPT = 64   # keys kept (a view of each camera and step in a library's kinds of render)
_lock = threading.Lock()   # one recording at a time (it patches moderngl's classes)
_active = None             # the Recording in progress
_INVALID: list = []        # moderngl.InvalidObject (imported by the first recording)


class Recording:
    """The calls of one recording: ``ops`` (callables, in order: what any view of the recorded
    kind replays), ``inline`` (the same with the GL calls of the view-dependent calls in place of
    those calls: what the recorded view replays; None if one of them made or read an object),
    ``objects`` and ``inline_objects`` (the GL objects each names), ``ok`` (False: abandoned, or
    ``busy``: another thread was recording)."""

    def __init__(self):
        self.ops: list = []
        self.inline: list | None = []
        self.objects: dict[int, object] = {}
        self.inline_objects: dict[int, object] = {}
        self.ok = True
        self.busy = False
        self.depth = 0   # inside a recorded call (its own calls not recorded)
        self.view = 0    # inside a view-dependent call (its calls recorded in ``inline`` only)
        self.thread = threading.get_ident()

    def add(self, op, *objects) -> None:
        """``op`` in ``inline`` and, outside a view-dependent call, in ``ops``."""
        if not self.view:
            self._add(self.ops, self.objects, op, objects)
        if self.inline is not None:
            self._add(self.inline, self.inline_objects, op, objects)

    def add_call(self, op, *objects) -> None:
        """A view-dependent call: ``op`` in ``ops`` (its own calls go to ``inline``)."""
        self._add(self.ops, self.objects, op, objects)

    @staticmethod
    def _add(ops: list, named: dict, op, objects) -> None:
        ops.append(op)
        for o in objects:
            if type(o).__name__ in _RELEASABLE:
                named[id(o)] = o

    def lost(self) -> None:
        """Something made, freed or read a GL object: outside a view-dependent call the
        recording is abandoned; inside one, only ``inline``."""
        if self.view:
            self.inline = None
        else:
            self.ok = False

    def call(self, fn, obj, args: tuple, kwargs: dict):
        """Run ``fn(obj, *args, **kwargs)``; calls nested in it are not recorded."""
        self.depth += 1
        try:
            return fn(obj, *args, **kwargs)
        except BaseException:
            self.ok = False
            raise
        finally:
            self.depth -= 1


def replayed(fn=None, *, view: bool = False, again=None):
    """Mark a glsim function whose calls a recording keeps as calls (with their arguments, run
    again on replay) rather than as the GL calls they make. ``view``: what it does depends on
    the view being drawn (it reads it from its arguments' state when it runs): kept as a call
    in what every view of the recorded kind replays, and as its GL calls in what the recorded
    view replays (``Recording.inline``). ``again(*args)``: what a replay runs for the call (a
    callable doing what the call does, in fewer steps), instead of the call itself."""
    if fn is None:
        return functools.partial(replayed, view=view, again=again)

    @functools.wraps(fn)
    def inner(*args):
        rec = _active
        if rec is None or rec.depth or rec.thread != threading.get_ident():
            return fn(*args)
        op = again(*args) if again is not None else functools.partial(fn, *args)
        if not view:
            rec.add(op, *args)
            return rec.call(lambda _, *a: fn(*a), None, args, {})
        if rec.view:   # (nested in another: its calls are that one's)
            return fn(*args)
        rec.add_call(op, *args)
        rec.view += 1
        try:
            return fn(*args)
        except BaseException:
            rec.ok = False
            raise
        finally:
            rec.view -= 1
    return inner


def _frozen(value):
    """A recorded argument that cannot change before the replay (arrays and buffers as bytes)."""
    return value.tobytes() if isinstance(value, (np.ndarray, bytearray, memoryview)) else value


def _recorder(rec: Recording):
    def wrap(fn, cls, name, kind):
        state = kind == "get" or (cls.__name__, name) in _LOOKUPS
        kept = not state and name in RECORDED.get(cls.__name__, ())

        @functools.wraps(fn)
        def inner(obj, *args, **kwargs):
            if rec.depth or rec.thread != threading.get_ident():
                return fn(obj, *args, **kwargs)
            if kept:
                args, kwargs = tuple(map(_frozen, args)), {k: _frozen(v) for k, v in kwargs.items()}
                op = (functools.partial(setattr, obj, name, *args) if kind == "set"
                      else functools.partial(operator.methodcaller(name, *args, **kwargs), obj))
                rec.add(op, obj, *args, *kwargs.values())
            elif not state or (cls.__name__, name) == ("Context", "error"):
                rec.lost()   # makes, frees or reads a GL object, or reads the error flag
            return rec.call(fn, obj, args, kwargs)
        return inner
    return wrap


@contextlib.contextmanager
def recording():
    """Record this thread's GL calls in the block (the yielded :class:`Recording`; ``ok`` is
    False if it was abandoned, or if another recording was in progress)."""
    global _active
    from glsim.backends.gl.timing import patched

    if not _INVALID:
        from moderngl import InvalidObject
        _INVALID.append(InvalidObject)
    rec = Recording()
    if not _lock.acquire(blocking=False):
        rec.ok, rec.busy = False, True
        yield rec
        return
    try:
        with patched(_recorder(rec)):
            _active = rec
            try:
                yield rec
            finally:
                _active = None
    finally:
        _lock.release()


def _weak(obj):
    """What gives ``obj`` back while it lives (a weak reference where it takes one)."""
    try:
        return weakref.ref(obj)
    except TypeError:
        return lambda: obj


def weak_refs(objects: tuple) -> tuple:
    """What gives each of ``objects`` back while it lives (a weak reference where it takes one)."""
    return tuple(map(_weak, objects))


def still(refs: tuple, objects: tuple) -> bool:
    """Whether ``refs`` (:func:`weak_refs`) give back ``objects``, each the same object."""
    return all(map(operator.is_, map(_CALL, refs), objects))


class _Record:
    __slots__ = ("refs", "ops", "objects", "result", "failures", "view", "inline", "inline_objects")

    def __init__(self, refs: tuple, failures: int = 0, rec: Recording | None = None, result=None, view=None):
        self.refs = weak_refs(refs)   # (a record does not keep a view's arrays alive)
        self.failures, self.result = failures, result
        self.ops = tuple(rec.ops) if rec is not None else None
        self.objects = tuple(rec.objects.values()) if rec is not None else ()
        inline = rec is not None and rec.inline is not None and view is not None
        self.view = _weak(view) if inline else None
        self.inline = tuple(rec.inline) if inline else None
        self.inline_objects = tuple(rec.inline_objects.values()) if inline else ()

    def live(self) -> bool:
        """Recorded, and no object it names released since (moderngl's release swaps an
        object's ``mglo`` for an InvalidObject)."""
        return self.ops is not None and _alive(self.objects)

    def replay(self, view) -> None:
        """The recorded calls: as made for ``view`` if it is the recorded view, else through
        its view-dependent calls."""
        if self.inline is not None and self.view() is view and _alive(self.inline_objects):
            collections.deque(map(_CALL, self.inline), maxlen=0)   # (each op in turn, looped in C)
        else:
            collections.deque(map(_CALL, self.ops), maxlen=0)


def _alive(objects: tuple) -> bool:
    return _INVALID[0] not in map(type, map(_MGLO, objects))


class Frames:
    """Recorded deformation passes by key (:meth:`run`); ``replays`` and ``recordings`` count
    what it did."""

    def __init__(self, most: int = FRAMES_KEPT):
        self.most = most
        self._kept: dict = {}
        self.replays = 0
        self.recordings = 0

    def run(self, key, refs: tuple, make, view=None):
        """``make()``'s result: replayed if ``key`` was recorded with the same objects ``refs``
        (compared by identity; the key holds their ids) and :meth:`_Record.live`; else made, and
        recorded if the key was made before (unless MAX_FAILURES recordings of it were
        abandoned; a thread's recordings wait for another's to end by not recording). ``view``:
        the view drawn (:meth:`_Record.replay`)."""
        hit = self._kept.get(key)
        if hit is None or not still(hit.refs, refs):
            keep(self._kept, key, _Record(refs), self.most)
            return make()
        if hit.live():
            hit.replay(view)
            self.replays += 1
            return hit.result
        if hit.failures >= MAX_FAILURES:
            return make()
        with recording() as rec:
            result = make()
        if rec.ok:
            self.recordings += 1
            keep(self._kept, key, _Record(refs, hit.failures, rec, result, view), self.most)
        else:   # (a thread that found another recording tries again next time)
            hit.ops, hit.objects, hit.failures = None, (), hit.failures + (not rec.busy)
        return result

    def clear(self) -> None:
        self._kept.clear()
