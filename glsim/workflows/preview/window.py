"""``glsim preview SCENE``: the desktop window (glfw).

Why glfw: it is a small, well-kept C library (pyGLFW wheels ship it for X11 and Wayland) that
makes a window with an OpenGL 4.5 core context and passes keys, mouse and resizes — all the
preview needs, since the core draws the whole frame itself (panel included) and the renderer
runs on the window's own context (one context, the renderer's shaders). moderngl-window would
add a framework around the same glfw; pyglet and rendercanvas bring their own event loops (and
rendercanvas draws through wgpu), which the frame-in-a-texture design does not need.
"""
from __future__ import annotations

import os

from glsim.errors import GlsimError

NO_DISPLAY = ("no display: `glsim preview` opens a window, but neither DISPLAY nor WAYLAND_DISPLAY is set. "
              "Use `glsim preview SCENE --screenshot out.png` (draws once through EGL, no display needed), "
              "or the notebook widget: `from glsim.workflows.preview import Widget; Widget(scene)` in "
              "JupyterLab or VS Code")


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


SPECIAL = {"RIGHT": "ArrowRight", "LEFT": "ArrowLeft", "UP": "ArrowUp", "DOWN": "ArrowDown", "ESCAPE": "Escape",
           "ENTER": "Enter", "BACKSPACE": "Backspace", "TAB": "Tab"}


def run(scene, size=(1280, 800), log_frames: bool = False, show_timings: bool = True, initial=None,
        make=None, **kwargs) -> int:
    """Open the window on ``scene`` (a Scene or a scene file) and run until it is closed (q,
    Escape or the close button). ``make(ctx)``: another view to show instead of the scene
    preview (the calibration-library pager), with the same frame and event interface."""
    import glfw

    from glsim.backends.gl.present import Presenter, window_context
    from glsim.workflows.preview.core import Preview

    if not has_display():
        raise GlsimError(NO_DISPLAY)
    if not glfw.init():
        raise GlsimError(NO_DISPLAY.replace("neither DISPLAY nor WAYLAND_DISPLAY is set",
                                            f"the display {os.environ.get('DISPLAY', '')!r} cannot be opened"))
    try:
        glfw.window_hint(glfw.CONTEXT_VERSION_MAJOR, 4)
        glfw.window_hint(glfw.CONTEXT_VERSION_MINOR, 5)
        glfw.window_hint(glfw.OPENGL_PROFILE, glfw.OPENGL_CORE_PROFILE)
        glfw.window_hint(glfw.OPENGL_FORWARD_COMPAT, True)
        win = glfw.create_window(int(size[0]), int(size[1]), "glsim preview", None, None)
        if not win:
            raise GlsimError("no OpenGL 4.5 window could be made on this display; use --screenshot or the "
                             "notebook widget")
        glfw.make_context_current(win)
        glfw.swap_interval(0)
        ctx = window_context()
        presenter = Presenter(ctx)
        pv = make(ctx) if make is not None else Preview(scene, size=size, ctx=ctx, **kwargs)
        pv.show_timings = show_timings
        if initial is not None:
            initial(pv)
        _connect(win, pv, glfw)
        shown = None
        while not glfw.window_should_close(win) and not pv.quit_requested:
            glfw.wait_events_timeout(0.0 if pv.busy else (pv.settle_seconds or 0.05))
            pv.tick()
            if pv.needs_redraw:
                frame = pv.frame()
                fb = glfw.get_framebuffer_size(win)
                presenter.show(frame, fb)
                glfw.swap_buffers(win)
                state = pv.log_state()
                if log_frames and state != shown:
                    print(state, flush=True)
                    shown = state
        presenter.release()
        pv.close()
        ctx.release()
        glfw.destroy_window(win)
    finally:
        glfw.terminate()
    return 0


def _connect(win, pv, glfw) -> None:
    state = {"x": 0.0, "y": 0.0, "buttons": set()}

    def mods_of(m):
        return tuple(name for bit, name in ((glfw.MOD_SHIFT, "Shift"), (glfw.MOD_CONTROL, "Control"),
                                            (glfw.MOD_ALT, "Alt")) if m & bit)

    def on_key(w, key, scancode, action, mods):
        if action not in (glfw.PRESS, glfw.REPEAT):
            return
        name = next((v for k, v in SPECIAL.items() if key == getattr(glfw, "KEY_" + k)), None)
        if name is None:   # printable keys by the keyboard layout's name (no input-method round trip)
            name = glfw.get_key_name(key, scancode)
            if name and mods & glfw.MOD_SHIFT:
                name = name.upper()
            elif key == glfw.KEY_SPACE:
                name = " "
        if name:
            pv.handle_event({"type": "key_down", "key": name, "modifiers": mods_of(mods)})

    def on_button(w, button, action, mods):
        b = {glfw.MOUSE_BUTTON_LEFT: 1, glfw.MOUSE_BUTTON_RIGHT: 2, glfw.MOUSE_BUTTON_MIDDLE: 3}.get(button, 0)
        kind = "pointer_down" if action == glfw.PRESS else "pointer_up"
        (state["buttons"].add if action == glfw.PRESS else state["buttons"].discard)(b)
        pv.handle_event({"type": kind, "x": state["x"], "y": state["y"], "button": b,
                         "buttons": tuple(state["buttons"]), "modifiers": mods_of(mods)})

    def on_move(w, x, y):
        state["x"], state["y"] = x, y
        pv.handle_event({"type": "pointer_move", "x": x, "y": y, "button": 0,
                         "buttons": tuple(state["buttons"]), "modifiers": ()})

    def on_scroll(w, dx, dy):
        pv.handle_event({"type": "wheel", "x": state["x"], "y": state["y"], "dx": -dx * 100, "dy": -dy * 100,
                         "modifiers": ()})

    def on_resize(w, width, height):
        fw, fh = glfw.get_framebuffer_size(win)
        if width and height:
            pv.handle_event({"type": "resize", "width": width, "height": height, "ratio": fw / width})

    glfw.set_key_callback(win, on_key)
    glfw.set_mouse_button_callback(win, on_button)
    glfw.set_cursor_pos_callback(win, on_move)
    glfw.set_scroll_callback(win, on_scroll)
    glfw.set_window_size_callback(win, on_resize)
