"""Interactive preview of a virtual stereo-DIC set-up: :class:`Preview` (the
headless core around one :class:`~glsim.render.Renderer`), ``Widget`` (Jupyter, jupyter-rfb)
and the desktop window of ``glsim preview`` (glfw). See docs/preview.md."""
from glsim.workflows.preview.core import Preview, draw_once

__all__ = ["Preview", "Widget", "draw_once"]


def __getattr__(name):
    if name == "Widget":   # jupyter-rfb and ipywidgets are imported only when asked for
        from glsim.workflows.preview.widget import Widget
        return Widget
    raise AttributeError(name)
