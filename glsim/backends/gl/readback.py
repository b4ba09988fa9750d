"""Read-backs that do not wait, so that a frame's GPU work overlaps the host's next frame.

A texture a frame needs on the host is copied into a pixel-pack buffer when the frame is
submitted (``Texture.read_into(Buffer)``: glGetTexImage into a bound GL_PIXEL_PACK_BUFFER
returns at once) and mapped when the frame is collected; by then the next frame's commands
are queued (:meth:`glsim.render.Renderer.render_many`). Buffers are recycled by size, so a
steady stream of frames allocates nothing.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from glsim.backends.gl.timing import waiting


class PackBuffers:
    """Pixel-pack buffers of one context, kept by size for reuse."""

    def __init__(self, ctx):
        self.ctx = ctx
        self._free: dict[int, list] = {}

    def take(self, nbytes: int):
        free = self._free.get(nbytes)
        if free:
            return free.pop()
        return self.ctx.buffer(reserve=nbytes)

    def give(self, buf) -> None:
        self._free.setdefault(buf.size, []).append(buf)

    def release(self) -> None:
        for bufs in self._free.values():
            for b in bufs:
                b.release()
        self._free.clear()


class Pending(NamedTuple):
    """A read queued into ``buffer``: an array of ``shape`` and ``dtype`` once fetched."""
    buffer: object
    shape: tuple[int, ...]
    dtype: np.dtype

    def fetch(self, pool: PackBuffers) -> np.ndarray:
        """The array (waits for the GPU if it is still writing); the buffer goes back to ``pool``."""
        out = np.empty(self.shape, self.dtype)
        with waiting():
            self.buffer.read_into(out)
        pool.give(self.buffer)
        return out


def read_texture(pool: PackBuffers, tex, dtype) -> Pending:
    """Queue the read of a 2-D texture (H, W[, components]) of ``dtype``."""
    W, H = tex.size
    shape = (H, W) if tex.components == 1 else (H, W, tex.components)
    dtype = np.dtype(dtype)
    buf = pool.take(math.prod(shape) * dtype.itemsize)
    tex.read_into(buf)
    return Pending(buf, shape, dtype)


def read_buffer(pool: PackBuffers, sources: list[tuple[object, int]]) -> Pending:
    """Queue a GPU-side copy of the leading ``size`` bytes of each source buffer, back to back,
    into one pack buffer (fetched as uint8 bytes)."""
    total = sum(size for _, size in sources)
    buf = pool.take(total)
    offset = 0
    for src, size in sources:
        pool.ctx.copy_buffer(buf, src, size=size, write_offset=offset)
        offset += size
    return Pending(buf, (total,), np.dtype(np.uint8))
