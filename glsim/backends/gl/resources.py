"""Every GL object a :class:`~glsim.backends.gl.backend.GLBackend` makes, in one owner, released
in one loop.

Objects are kept by value: a named object by its key (a tuple of its size, format and role:
``get``), the latest of a kind (``latest``: one camera size's lists, one step's patch buffers),
scratch textures pooled by (size, components, dtype) and lent to one frame at a time
(``borrow`` / ``give_back``), the framebuffer drawing into given textures and the vertex array
of a program keyed by those objects themselves. Programs are the
:class:`~glsim.backends.gl.programs.ProgramCache`'s. A stream of frames of one kind allocates
nothing after its first.
"""
from __future__ import annotations

from collections.abc import Callable

from glsim.backends.gl.readback import PackBuffers


def _objects(value) -> list:
    """The GL objects in ``value`` (one, or nested tuples of them; other items ignored)."""
    if isinstance(value, (tuple, list)):
        return [o for v in value for o in _objects(v)]
    return [value] if hasattr(value, "release") else []


class Resources:
    """The GL objects of one backend on ``ctx``; ``pack``: its pixel-pack buffers."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.pack = PackBuffers(ctx)
        self._named: dict[tuple, object] = {}
        self._free: dict[tuple, list] = {}      # scratch (textures, framebuffer) by (size, components, dtype)
        self.lent: list = []                    # scratch entries a frame holds (given back after its reads)

    def get(self, key: tuple, make: Callable[[], object]):
        """The object(s) kept under ``key``, made by ``make()`` the first time."""
        if key not in self._named:
            self._named[key] = make()
        return self._named[key]

    def has(self, key: tuple) -> bool:
        return key in self._named

    def latest(self, kind: str, key: tuple, make: Callable[[], object]):
        """As :meth:`get` under (``kind``, ``key``), keeping one key per ``kind``: another key's
        objects of that kind are released (a renderer draws one size, one step after another)."""
        full = (kind, *key)
        if full not in self._named:
            for k in [k for k in self._named if k[0] == kind]:
                self._drop(k)
        return self.get(full, make)

    def texture(self, size: tuple[int, int], role: str, components: int = 1, dtype: str = "f4"):
        """This backend's texture of ``size`` for ``role`` (one per size, role and format): a
        frame's pixel passes draw into the same objects every frame; the GL orders a frame's
        draws after the reads queued from the last."""
        return self.get(("texture", size, role, components, dtype),
                        lambda: self.ctx.texture(size, components, dtype=dtype))

    def framebuffer(self, colors: tuple = (), depth=None):
        """The framebuffer drawing into the textures ``colors`` (and ``depth``), made once."""
        def make():
            if not colors:
                return self.ctx.framebuffer(depth_attachment=depth)
            return self.ctx.framebuffer(color_attachments=list(colors), depth_attachment=depth)
        return self.get(("framebuffer", tuple(colors), depth), make)

    def vertex_array(self, prog, index=None):
        """``prog``'s attribute-less vertex array (with the uint32 ``index`` buffer if given)."""
        kw = {"index_buffer": index, "index_element_size": 4} if index is not None else {}
        return self.get(("vertex_array", prog, index), lambda: self.ctx.vertex_array(prog, [], **kw))

    def borrow(self, size: tuple[int, int], components: tuple[int, ...], dtype: str):
        """Scratch textures of one shape with their framebuffer, lent until :meth:`give_back`."""
        key = (size, components, dtype)
        free = self._free.setdefault(key, [])
        if free:
            entry = free.pop()
        else:
            outs = tuple(self.ctx.texture(size, n, dtype=dtype) for n in components)
            entry = (outs, self.ctx.framebuffer(color_attachments=list(outs)), key)
        self.lent.append(entry)
        return entry

    def give_back(self) -> None:
        """Every lent scratch entry back to its pool (the GL orders their next use after the
        reads queued from them)."""
        for entry in self.lent:
            self._free[entry[2]].append(entry)
        self.lent.clear()

    def _drop(self, key) -> None:
        """Release the objects kept under ``key`` and those made from them."""
        value = self._named.pop(key)
        gone = set(_objects(value))
        for k in [k for k in self._named if k[0] in ("framebuffer", "vertex_array")
                  and gone.intersection(_objects(k[1:]))]:
            for obj in _objects(self._named.pop(k)):
                obj.release()
        for obj in gone:
            obj.release()

    def release(self) -> None:
        """Release everything (framebuffers and vertex arrays before what they name)."""
        self.give_back()
        self.ctx.detect_framebuffer(0).use()   # (moderngl re-binds the current framebuffer when it makes the next)
        views = [k for k in self._named if k[0] in ("framebuffer", "vertex_array")]
        ordered = views + [k for k in self._named if k not in views]
        entries = [e for free in self._free.values() for e in free]
        for obj in [o for k in ordered for o in _objects(self._named[k])] + [o for e in entries for o in (e[1], *e[0])]:
            obj.release()
        self._named.clear()
        self._free.clear()
        self.pack.release()
