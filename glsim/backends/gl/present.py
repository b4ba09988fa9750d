"""Showing an RGB frame in a window's OpenGL context (the desktop preview): a moderngl
context on the window toolkit's current context, one texture and a full-screen triangle. The
preview's renderer can use the same context (:func:`window_context`)."""
from __future__ import annotations

import numpy as np

from glsim.errors import GLUnavailableError

_VERT = """#version 330
out vec2 uv;
void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    uv = vec2(p.x, 1.0 - p.y);   // frame row 0 (top) at the top of the window
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"""
_FRAG = """#version 330
uniform sampler2D frame;
in vec2 uv;
out vec4 colour;
void main() { colour = vec4(texture(frame, uv).rgb, 1.0); }
"""


def window_context(require: int = 450):
    """A moderngl context on the current (window) context; GLUnavailableError if it is older
    than ``require`` (the renderer needs 4.5)."""
    import moderngl

    try:
        return moderngl.create_context(require=require)
    except Exception as exc:
        raise GLUnavailableError(f"the window's OpenGL context cannot be used ({exc})") from exc


class Presenter:
    """Draws H×W×3 uint8 frames into the default framebuffer of ``ctx`` (a window's)."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.prog = ctx.program(vertex_shader=_VERT, fragment_shader=_FRAG)
        self.vao = ctx.vertex_array(self.prog, [])
        self.tex = None

    def show(self, frame: np.ndarray, size: tuple[int, int]) -> None:
        """Draw ``frame`` over the whole framebuffer of ``size`` (W, H) px (scaled if they differ)."""
        ctx = self.ctx
        h, w = frame.shape[:2]
        if self.tex is None or self.tex.size != (w, h):
            if self.tex is not None:
                self.tex.release()
            self.tex = ctx.texture((w, h), 3, dtype="f1")
            self.tex.filter = (ctx.NEAREST, ctx.NEAREST)
        ctx.unpack_alignment = 1   # rows of w·3 bytes
        self.tex.write(np.ascontiguousarray(frame, np.uint8).tobytes())
        screen = ctx.detect_framebuffer(0)
        screen.use()
        screen.viewport = (0, 0, *size)
        ctx.disable(ctx.DEPTH_TEST)
        self.tex.use(0)
        self.prog["frame"].value = 0
        self.vao.render(ctx.TRIANGLES, vertices=3)

    def read(self, size: tuple[int, int]) -> np.ndarray:
        """The window's back buffer as H×W×3 uint8, top row first."""
        W, H = size
        data = self.ctx.detect_framebuffer(0).read(viewport=(0, 0, W, H), components=3, alignment=1)
        return np.frombuffer(data, np.uint8).reshape(H, W, 3)[::-1].copy()

    def release(self) -> None:
        for obj in (self.tex, self.vao, self.prog):
            if obj is not None:
                obj.release()
