"""``Widget(scene)``: the preview in Jupyter (JupyterLab, VS Code) — a jupyter-rfb remote frame
buffer (the core's frame, with the same panel, keys and mouse as the window) beside ipywidgets
controls. Needs the ``notebook`` extra (jupyter-rfb, ipywidgets)."""
from __future__ import annotations

import asyncio
import math
import time

import ipywidgets as ipw
from jupyter_rfb import RemoteFrameBuffer

from glsim.workflows.preview.controls import OVERLAYS
from glsim.workflows.preview.core import Preview


class Widget(RemoteFrameBuffer):
    """The preview of ``scene`` (a Scene or a scene file) as a notebook widget. Displaying it
    shows the frame and the ipywidgets controls (:attr:`ui`); :attr:`core` is the
    :class:`~glsim.workflows.preview.core.Preview` it drives."""

    def __init__(self, scene, size=(1100, 680), ctx=None, **kwargs):
        super().__init__(css_width=f"{size[0]}px", css_height=f"{size[1]}px", resizable=True)
        self.core = Preview(scene, size=size, ctx=ctx, **kwargs)
        self._syncing = False
        self._widgets: dict[str, ipw.Widget] = {}
        self.controls = self._make_controls()
        self.ui = ipw.HBox([self, self.controls])
        self.frames_drawn = 0

    # ---- jupyter_rfb --------------------------------------------------------------------------
    def get_frame(self):
        """The core's frame (H×W×3 uint8); a fast one is followed by its refinement."""
        frame = self.core.frame()
        self.frames_drawn += 1
        if self.core.needs_redraw:
            self._later(self.core.settle_seconds + 0.02)
        self._sync_from_core()
        return frame

    def handle_event(self, event):
        """Pointer, wheel, key and resize events from the browser go to the core."""
        if self.core.handle_event(event):
            self.request_draw()
        self._sync_from_core()

    def _later(self, delay: float) -> None:
        try:
            asyncio.get_running_loop().call_later(delay, self.request_draw)
        except RuntimeError:   # no event loop (tests drive the widget by hand)
            pass

    def close(self, *args, **kwargs):
        super().close(*args, **kwargs)
        core = getattr(self, "core", None)
        if core is not None and core.renderer is not None:
            core.close()

    def _ipython_display_(self, **kwargs):
        from IPython.display import display
        display(self.ui)

    # ---- ipywidgets controls -----------------------------------------------------------------
    def _make_controls(self) -> ipw.Widget:
        core, rows = self.core, []
        play = ipw.Play(value=core.p.step, min=0, max=core.model.n_steps - 1, interval=int(core.play_interval * 1000))
        for name, c in core.controls.items():
            if c.kind == "button" or name.startswith("overlay:") or name == "component":
                continue
            value = core.get(name)
            desc = c.label + (f" ({c.unit})" if c.unit else "")
            style = {"description_width": "110px"}
            layout = ipw.Layout(width="330px")
            if c.kind == "toggle":
                w = ipw.Checkbox(value=bool(value), description=desc, style=style, layout=layout)
            elif c.kind == "choice":
                w = ipw.Dropdown(options=list(c.options), value=c.options[value] if name == "camera" else value,
                                 description=desc, style=style, layout=layout)
            elif c.kind == "int":
                w = ipw.IntSlider(value=int(value), min=int(c.lo), max=int(c.hi), step=1, description=desc,
                                  style=style, layout=layout)
            else:
                st, v = c.step / 4, float(value)   # the grid through the value: the slider keeps it as it is
                lo, hi = v - math.floor((v - c.lo) / st) * st, v + math.floor((c.hi - v) / st) * st
                w = ipw.FloatSlider(value=v, min=lo, max=hi, step=st, description=desc,
                                    readout_format=".4g", style=style, layout=layout)
            w.observe(lambda change, n=name: self._from_widget(n, change["new"]), names="value")
            self._widgets[name] = w
            rows.append(ipw.HBox([w, play]) if name == "step" else w)
        ipw.jslink((play, "value"), (self._widgets["step"], "value"))
        overlays = []
        for k in OVERLAYS:
            w = ipw.Checkbox(value=False, description=k, indent=False, layout=ipw.Layout(width="150px"))
            w.observe(lambda change, n=f"overlay:{k}": self._from_widget(n, change["new"]), names="value")
            self._widgets[f"overlay:{k}"] = w
            overlays.append(w)
        comp = ipw.Dropdown(options=list(core.controls["component"].options), value=core.p.component,
                            description="component", layout=ipw.Layout(width="220px"))
        comp.observe(lambda change: self._from_widget("component", change["new"]), names="value")
        self._widgets["component"] = comp
        self.path = ipw.Text(value=str(core.save_path), description="scene file", layout=ipw.Layout(width="330px"))
        self.shot = ipw.Text(value=str(core.screenshot_path), description="screenshot", layout=ipw.Layout(width="330px"))
        save = ipw.Button(description="save scene TOML")
        snap = ipw.Button(description="save screenshot PNG")
        self.status = ipw.HTML("")
        save.on_click(lambda _: self._status(f"saved {core.save(self.path.value)}"))
        snap.on_click(lambda _: self._status(f"saved {core.screenshot(self.shot.value)}"))
        box = ipw.VBox(rows + [ipw.HTML("<b>overlays</b>"), ipw.GridBox(overlays, layout=ipw.Layout(
            grid_template_columns="repeat(2, 160px)")), comp, self.path, save, self.shot, snap, self.status],
            layout=ipw.Layout(max_height="700px", overflow="auto"))
        return box

    def _status(self, text: str) -> None:
        self.status.value = text
        self.request_draw()

    def _from_widget(self, name: str, value) -> None:
        if self._syncing:
            return
        core = self.core
        c = core.controls.get(name)
        if c is not None and c.kind == "slider" and abs(value - core.get(name)) <= 1e-6 * c.step:
            return   # the slider snapping its value to its step grid, not the user
        if c is not None and c.kind == "slider":   # a slider drag: fast frames until it settles
            core.set(name, value, dragging=True)
            core.dragging = False
            core._settle_until = time.monotonic() + 0.3
        else:
            core.set(name, value)
        self.request_draw()
        self._sync_from_core()

    def _sync_from_core(self) -> None:
        """Show the core's values (keys and the frame's own panel change them too)."""
        self._syncing = True
        try:
            for name, w in self._widgets.items():
                v = self.core.get(name)
                if name == "camera":
                    v = self.core.controls["camera"].options[v]
                if w.value != v:
                    w.value = v
        finally:
            self._syncing = False
