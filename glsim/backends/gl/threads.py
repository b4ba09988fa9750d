"""Using one headless EGL context from more than one thread (Jupyter calls a widget's drawing
from another thread than the cell that made it): an EGL context is current in at most one
thread, so :class:`EGLBinding` makes it current around each use and releases it after."""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import threading


class EGLBinding:
    """Captures the EGL context current in the calling thread (the one ``create_context`` just
    made); :meth:`current` binds it to the calling thread for a block (re-entrant, one thread at a
    time) and releases it afterwards. Without EGL (or with no current EGL context) it does nothing."""

    def __init__(self):
        self._lock = threading.RLock()
        self._depth = 0
        self.dpy = self.ctx = None
        try:
            egl = ctypes.CDLL(ctypes.util.find_library("EGL") or "libEGL.so.1")
            for name in ("eglGetCurrentDisplay", "eglGetCurrentContext"):
                getattr(egl, name).restype = ctypes.c_void_p
            egl.eglMakeCurrent.argtypes = [ctypes.c_void_p] * 4
            egl.eglMakeCurrent.restype = ctypes.c_uint
            self._egl = egl
            self.dpy, self.ctx = egl.eglGetCurrentDisplay(), egl.eglGetCurrentContext()
        except (OSError, AttributeError):
            self._egl = None

    @property
    def active(self) -> bool:
        return bool(self._egl is not None and self.dpy and self.ctx)

    def release(self) -> None:
        """Unbind the context from the calling thread (so that another thread can bind it)."""
        if self.active and self._egl.eglGetCurrentContext() == self.ctx:
            self._egl.eglMakeCurrent(self.dpy, None, None, None)

    @contextlib.contextmanager
    def current(self):
        if not self.active:
            yield
            return
        with self._lock:
            if self._depth == 0 and self._egl.eglGetCurrentContext() != self.ctx:
                if not self._egl.eglMakeCurrent(self.dpy, None, None, self.ctx):
                    raise RuntimeError("the preview's EGL context could not be made current in this thread")
            self._depth += 1
            try:
                yield
            finally:
                self._depth -= 1
                if self._depth == 0:
                    self.release()
