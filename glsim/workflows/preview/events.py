"""Input of the preview: jupyter_rfb's event dicts (the window translates its own into these)
and the keys. :class:`Events` is a part of :class:`~glsim.workflows.preview.core.Preview` and
acts through its controls (``set``, ``add``, ``cycle``, ``press``) and its view state."""
from __future__ import annotations

import dataclasses

import numpy as np

from glsim.workflows.preview import overlays as ov

KEYS = {            # key → (action, argument)
    "ArrowRight": ("add", ("step", 1)), "ArrowLeft": ("add", ("step", -1)), " ": ("press", "play"),
    "c": ("cycle", "camera"), "m": ("cycle", "mode"), "1": ("toggle", "lighting"), "2": ("toggle", "dof"),
    "3": ("toggle", "noise"), "4": ("toggle", "psf"), "5": ("toggle", "vignetting"), "6": ("toggle", "fpn"),
    "7": ("toggle", "motion"), "d": ("toggle", "overlay:displacement"), "v": ("cycle", "component"),
    "e": ("toggle", "overlay:edges"), "o": ("toggle", "overlay:overlap"), "f": ("toggle", "overlay:coc"),
    "k": ("toggle", "overlay:clipped"), "z": ("toggle", "overlay:speckle"), "g": ("toggle", "overlay:range"),
    "[": ("add", ("stereo_angle", -1)), "]": ("add", ("stereo_angle", 1)), "-": ("add", ("distance", -1)),
    "=": ("add", ("distance", 1)), "+": ("add", ("distance", 1)), ",": ("add", ("focal_length", -1)),
    ".": ("add", ("focal_length", 1)), "n": ("add", ("f_number", 1)), "N": ("add", ("f_number", -1)),
    "w": ("press", "save"), "p": ("press", "screenshot"), "r": ("view", "reset"), "h": ("view", "help"),
}


class Events:
    """Pointer, wheel, key and resize events of :class:`~glsim.workflows.preview.core.Preview`."""

    def resize(self, width: int, height: int) -> None:
        size = (max(320, int(width)), max(240, int(height)))
        if size != self.size:
            self.size = size
            self._dirty = True

    def _hit(self, x: float, y: float):
        for (bx, by, bw, bh), what in reversed(self._hits):
            if bx <= x < bx + bw and by <= y < by + bh:
                return what, (bx, by, bw, bh)
        return None, None

    def handle_event(self, event: dict) -> bool:
        """Apply one input event; True when the frame must be redrawn. Events are jupyter_rfb's
        dicts: ``type`` (or ``event_type``) pointer_down/pointer_move/pointer_up/wheel/key_down/
        resize, with x, y (logical px), button (1 left, 2 right, 3 middle), modifiers, dx/dy,
        key, width/height/ratio."""
        kind = event.get("type") or event.get("event_type")
        ratio = event.get("ratio", event.get("pixel_ratio", self._ratio)) or 1.0
        mods = tuple(event.get("modifiers", ()))
        x, y = event.get("x", 0) * self._ratio, event.get("y", 0) * self._ratio
        if kind == "resize":
            self._ratio = float(ratio)
            self.resize(event["width"] * self._ratio, event["height"] * self._ratio)
        elif kind == "pointer_down":
            self._pointer_down(x, y, event.get("button", 1), mods)
        elif kind == "pointer_move" and self._drag is not None:
            self._pointer_move(x, y)
        elif kind == "pointer_up":   # ends any drag: the next frame is the refinement
            self.dragging = False
            self._drag = None
        elif kind == "wheel":
            self._wheel(x, y, event.get("dy", 0.0))
        elif kind == "key_down":
            self.key(event.get("key", ""), mods)
        return self.needs_redraw

    def key(self, key: str, modifiers=()) -> None:
        if key in ("q", "Escape"):
            self.quit_requested = True
            return
        action = KEYS.get(key)
        if action is None:
            return
        what, arg = action
        if what == "add":
            self.add(*arg)
        elif what == "toggle":
            self.set(arg, not self.get(arg))
        elif what == "cycle":
            self.cycle(arg)
        elif what == "press":
            self.press(arg)
        elif arg == "reset":
            self.orbit = dataclasses.replace(self._orbit0)
            self._dirty = True
        else:
            self.show_help = not self.show_help
            self._dirty = True

    def _pointer_down(self, x, y, button, mods) -> None:
        what, box = self._hit(x, y)
        if what is None:
            return
        kind, arg = what
        if kind == "control":
            c = self.controls[arg]
            bx, by, bw, bh = box
            if c.kind == "toggle":
                self.set(c.name, not self.get(c.name))
            elif c.kind == "button":
                self.press(c.name)
            elif x >= bx + bw - 40:
                steps = -1 if x < bx + bw - 24 else 1
                if c.kind == "choice":
                    self.cycle(c.name, steps)
                else:
                    self.add(c.name, steps)
            elif c.kind == "choice":
                self.cycle(c.name, -1 if button == 2 else 1)
            else:
                self._drag = ("slider", c.name, x, float(self.get(c.name)), bw - 52)
        elif kind == "tile":
            if self.p.camera != arg:
                self.set("camera", arg)
            self._drag = ("target", arg, x, y, (self.p.target_x, self.p.target_y, self.p.target_z))
        elif kind == "rig":
            pan = button in (2, 3) or "Shift" in mods
            o = self.orbit
            self._drag = ("pan" if pan else "orbit", None, x, y, (o.azimuth, o.elevation, o.pan))

    def _pointer_move(self, x, y) -> None:
        kind, arg, x0 = self._drag[:3]
        if kind == "slider":
            c = self.controls[arg]
            v0, width = self._drag[3], max(self._drag[4], 20)
            v = v0 + (x - x0) / width * (c.hi - c.lo)
            v = min(max(v, c.lo), c.hi)
            if c.kind == "int":
                v = int(round(v))
                if v == self.get(arg):
                    return
                self.set(arg, v)
            else:
                self.set(arg, v, dragging=True)
        elif kind == "target":
            y0, t0 = self._drag[3], self._drag[4]
            cam = self.scene.cameras[arg]
            box = self._layout()["tiles"][arg]
            mm = ov.mm_per_px(cam, self.model.rig.target[None]) * cam.width / box[2]
            R = self.model.base.cameras[arg].rotation
            d = -(x - x0) * mm * R[0] - (y - y0) * mm * R[1]
            self.set("target_x", t0[0] + d[0], dragging=True)
            self.set("target_y", t0[1] + d[1], dragging=True)
            self.set("target_z", t0[2] + d[2], dragging=True)
        else:
            y0, (az, el, pan) = self._drag[3], self._drag[4]
            o = self.orbit
            if kind == "orbit":
                o.azimuth = az - (x - x0) * 0.4
                o.elevation = float(np.clip(el + (y - y0) * 0.4, -89, 89))
            else:
                k = o.distance / max(self._layout()["rig"][3], 1)
                o.pan = (pan[0] - (x - x0) * k, pan[1] - (y - y0) * k)
            self._dirty = True

    def _wheel(self, x, y, dy) -> None:
        what, _ = self._hit(x, y)
        if what is None or dy == 0:
            return
        if what[0] == "rig":
            self.orbit.distance *= 1.1 ** (1 if dy > 0 else -1)
            self._dirty = True
        elif what[0] == "tile":
            self.add("distance", 1 if dy > 0 else -1)
        elif what[0] in ("control", "panel"):   # scroll the panel
            self._panel_offset += 3 if dy > 0 else -3
            self._dirty = True
