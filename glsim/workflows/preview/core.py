"""The preview core: one scene, its live parameters and one :class:`~glsim.render.Renderer`
(one GL context, the renderer's own shaders), drawn into one RGB frame — both cameras side by
side as they will record, the 3-D rig view, the overlays and a control panel. Headless: the
desktop window, the notebook widget and ``--screenshot`` only show :meth:`Preview.frame` and
feed :meth:`Preview.handle_event` (jupyter_rfb's event dicts)."""
from __future__ import annotations

import dataclasses
import math
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import cv2
import numpy as np

from glsim.errors import GlsimError
from glsim.render import Renderer
from glsim.scene import Scene, load_scene
from glsim.scene.camera import Camera
from glsim.io.fe import specimen_mesh
from glsim.workflows.preview import draw, overlays as ov
from glsim.workflows.preview.controls import OVERLAYS, Control, Model, moved_light
from glsim.workflows.preview.sceneio import pinned_speckle, reference_inputs, save_scene

TRUTH_OVERLAYS = ("displacement", "overlap", "coc")
ROW = 19            # panel row height, px
DRAG_TRUTH_PX = 60_000  # truth pixels per camera while dragging
SETTLE_S = 0.25     # refine this long after the last wheel or key step
KEYS = {            # key → (action, argument)
    "ArrowRight": ("add", ("step", 1)), "ArrowLeft": ("add", ("step", -1)), " ": ("press", "play"),
    "c": ("cycle", "camera"), "m": ("cycle", "mode"), "1": ("toggle", "lighting"), "2": ("toggle", "dof"),
    "3": ("toggle", "noise"), "d": ("toggle", "overlay:displacement"), "v": ("cycle", "component"),
    "e": ("toggle", "overlay:edges"), "o": ("toggle", "overlay:overlap"), "f": ("toggle", "overlay:coc"),
    "k": ("toggle", "overlay:clipped"), "z": ("toggle", "overlay:speckle"), "g": ("toggle", "overlay:range"),
    "[": ("add", ("stereo_angle", -1)), "]": ("add", ("stereo_angle", 1)), "-": ("add", ("distance", -1)),
    "=": ("add", ("distance", 1)), "+": ("add", ("distance", 1)), ",": ("add", ("focal_length", -1)),
    ".": ("add", ("focal_length", 1)), "n": ("add", ("f_number", 1)), "N": ("add", ("f_number", -1)),
    "w": ("press", "save"), "p": ("press", "screenshot"), "r": ("view", "reset"), "h": ("view", "help"),
}


def _gl(method):
    """Run ``method`` with the preview's GL context bound to the calling thread."""
    import functools

    @functools.wraps(method)
    def wrapper(self, *args, **kwargs):
        egl = getattr(self, "_egl", None)
        if egl is None:
            return method(self, *args, **kwargs)
        with egl.current():
            return method(self, *args, **kwargs)
    return wrapper


def scaled_camera(cam: Camera, scale: float) -> Camera:
    """``cam`` at ``scale`` times its size (pixel centres kept: c' = (c + ½)·s − ½)."""
    W, H = cam.size
    w, h = max(1, round(W * scale)), max(1, round(H * scale))
    sx, sy = w / W, h / H
    return dataclasses.replace(cam, size=(w, h), fx=cam.fx * sx, fy=cam.fy * sy, cx=(cam.cx + 0.5) * sx - 0.5,
                               cy=(cam.cy + 0.5) * sy - 0.5, skew=cam.skew * sx)


def scaled_scene(scene: Scene, scale: float) -> Scene:
    """Every camera at ``scale``; the depth of field keeps its blur in the cameras' own pixels."""
    if scale == 1.0:
        return scene
    cams = tuple(scaled_camera(c, scale) for c in scene.cameras)
    s = cams[0].size[0] / scene.cameras[0].size[0]
    optics = scene.optics and dataclasses.replace(scene.optics, pixel_pitch=scene.optics.pixel_pitch / s,
                                                  coc_px=scene.optics.coc_px * s)
    return dataclasses.replace(scene, cameras=cams, optics=optics)


def display_grey(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """What the camera records (quantised to its bit depth, clipped) as 8-bit display grey."""
    top = (1 << bit_depth) - 1
    q = np.clip(np.rint(np.asarray(image, np.float64) * top), 0, top)
    return (q if bit_depth == 8 else np.rint(q * (255.0 / top))).astype(np.uint8)


class Preview:
    """The preview of a scene: live parameters (:attr:`p`), the edited :attr:`scene`, and the
    frame (H×W×3 uint8) that shows it.

    ``size``: the frame (W, H) px; ``drag_width``: width (px) the cameras are rendered at while a
    control is dragged (default: their width on screen), in ``fast`` mode; when the drag ends
    they are rendered again at full size in the scene's mode. ``ctx``: a GL context to share.
    """

    def __init__(self, scene: Scene | str | Path, size=(1280, 800), ctx=None, drag_width: int | None = None,
                 save_path: str | Path | None = None, screenshot_path: str | Path | None = None):
        from glsim.backends.gl.context import create_context

        if not isinstance(scene, Scene):
            path = Path(scene)
            scene = load_scene(path)
            stem = path.stem
        else:
            stem = "scene"
        self.save_path = Path(save_path or f"{stem}_preview.toml")
        self.screenshot_path = Path(screenshot_path or f"{stem}_preview.png")
        self.size = (int(size[0]), int(size[1]))
        self.drag_width = drag_width
        self.mesh = specimen_mesh(scene)
        self.model = Model(scene, self.mesh.nodes, self.mesh.n_steps)
        self.p = self.model.params()
        self.lights = list(self.model.lighting.lights)
        self.controls: dict[str, Control] = {c.name: c for c in self.model.controls()}
        self._own_ctx = ctx is None
        self.ctx = ctx if ctx is not None else create_context()
        from glsim.backends.gl.threads import EGLBinding
        # our own EGL context is bound only while we draw: Jupyter draws from another thread
        self._egl = EGLBinding() if self._own_ctx else None
        self.renderer: Renderer | None = None
        self.reference_uploads = 0          # how often a reference (speckle) was made and uploaded
        self._built = None                  # reference_inputs of the scene the reference was made from
        self._tmp = None                    # the preview's own folder (pinned reference images)
        self.messages: list[str] = []
        self.scene = self._compose()
        self._install(self.scene)
        rig = self.model.rig
        middle = (rig.target + np.mean([c.center for c in rig.cameras], axis=0)) / 2
        o = draw.Orbit(middle, rig.up, -self._mean_view(), 1.5 * rig.distance, azimuth=55.0, elevation=25.0)
        self._orbit0 = dataclasses.replace(o)
        self.orbit = o
        self.dragging = False               # a scene-changing drag is under way: render fast
        self.show_help = False
        self._version = 0                   # bumped on every scene or step change
        self._results = None                # (version, quality, [Result])
        self._truths = None                 # (version, quality, scale, [Truth])
        self._speckle_cache: dict = {}
        self._frame = None
        self._frame_quality = None
        self._dirty = True
        self._drag = None
        self._settle_until = 0.0
        self._last_play = 0.0
        self.play_interval = 0.6
        self.timings: dict[str, float] = {}
        self._hits: list[tuple] = []
        self._ratio = 1.0
        self.quit_requested = False
        if self._egl is not None:
            self._egl.release()
        self._panel_offset = 0
        self.show_timings = True           # render times in the frame (off: reproducible frames)

    # ---- scene -------------------------------------------------------------------------------
    def _mean_view(self) -> np.ndarray:
        z = np.mean([c.rotation[2] for c in self.model.base.cameras], axis=0)
        return z / np.linalg.norm(z)

    def _compose(self) -> Scene:
        """The edited scene from the loaded one and :attr:`p`. While the speckle settings are
        those the current reference was made with, the reference is kept: if camera 1 moved
        or zoomed, the scene's [speckle] becomes that very image and camera
        (:func:`~glsim.workflows.preview.sceneio.pinned_speckle`)."""
        scene = self.model.scene(self.p, self.lights)
        built = self._built
        if built is not None and reference_inputs(scene) != built:
            speckle, specimen, cam0, base = built
            if (scene.speckle, scene.specimen, scene.base_dir) == (speckle, specimen, base):
                pin = pinned_speckle(self.renderer.reference, self._private(), f"reference_{self.reference_uploads}.tif")
                scene = dataclasses.replace(scene, speckle=pin)
        return scene

    def _private(self) -> str:
        if self._tmp is None:
            self._tmp = tempfile.mkdtemp(prefix="glsim-preview-")
        return self._tmp

    def _install(self, scene: Scene) -> None:
        """Point the renderer at ``scene``; make a new reference only when the scene asks for
        another one (new speckle size or seed), on the same GL context."""
        pinned = self._tmp is not None and scene.speckle.image and Path(scene.speckle.image).parent == Path(self._tmp)
        if self.renderer is not None and (pinned or reference_inputs(scene) == self._built):
            self.renderer.scene = scene
            return
        new = Renderer(scene, "gl", ctx=self.ctx, mesh=self.mesh)
        if self.renderer is not None:
            self.renderer.close()
        self.renderer = new
        self.reference_uploads += 1
        self._built = reference_inputs(scene)

    @_gl
    def close(self) -> None:
        if self.renderer is not None:
            self.renderer.close()
            self.renderer = None
        if self._own_ctx and self.ctx is not None:
            self.ctx.release()
        self.ctx = None
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None

    def __enter__(self) -> "Preview":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- controls ----------------------------------------------------------------------------
    def get(self, name: str):
        """The value of control ``name`` (``overlay:NAME`` for an overlay)."""
        if name.startswith("overlay:"):
            return self.p.overlays[name[8:]]
        return getattr(self.p, name)

    @_gl
    def set(self, name: str, value, dragging: bool = False) -> bool:
        """Set control ``name``; ``dragging``: more values follow at once (render fast until the
        drag ends). Returns False (and keeps the old value, with the reason in
        :attr:`messages`) when the scene refuses the value."""
        if name.startswith("overlay:"):
            key = name[8:]
            if key not in OVERLAYS:
                raise KeyError(f"no overlay {key!r}; overlays: {', '.join(OVERLAYS)}")
            self.p.overlays[key] = bool(value)
            self._dirty = True
            return True
        if name in ("save", "screenshot", "play"):
            return self.press(name)
        if name not in self.controls:
            raise KeyError(f"no control {name!r}; controls: {', '.join(self.controls)}")
        c = self.controls[name]
        if c.kind == "choice":
            if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and name == "camera":
                if not 0 <= value < len(c.options):
                    raise ValueError(f"camera: {value} is not one of 0…{len(c.options) - 1}")
                value = int(value)
            elif value not in c.options:
                raise ValueError(f"{name}: {value!r} is not one of {c.options}")
            elif name == "camera":
                value = c.options.index(value)
        elif c.kind == "int":
            value = int(round(float(value)))
            value = min(max(value, int(c.lo)), int(c.hi)) if name in ("step", "light", "camera") else value
        elif c.kind == "toggle":
            value = bool(value)
        elif c.kind == "slider":
            value = float(value)
        old_p = dataclasses.replace(self.p, overlays=dict(self.p.overlays))
        old_lights = list(self.lights)
        setattr(self.p, name, value)
        self._dirty = True
        if not c.scene:
            return True
        if name == "light":
            li = self.lights[value]
            self.p.light_intensity = li.intensity
            self.p.light_x, self.p.light_y, self.p.light_z = li.position
        elif name.startswith("light_"):
            i = self.p.light
            self.lights[i] = moved_light(self.lights[i], (self.p.light_x, self.p.light_y, self.p.light_z),
                                         self.p.light_intensity, self.model.rig.target)
        if name == "step":
            self._version += 1
            self.dragging = dragging
            return True
        try:
            scene = self._compose()
            self._install(scene)
        except GlsimError as exc:
            self.p, self.lights = old_p, old_lights
            self._note(f"{name} = {value:g} refused: {exc}" if isinstance(value, float) else f"{name} refused: {exc}")
            self._install(self.scene)
            return False
        self.scene = scene
        self._version += 1
        self.dragging = dragging
        return True

    def add(self, name: str, steps: int) -> bool:
        """Step control ``name`` by ``steps`` of its step size (keys and the panel's −/+)."""
        c = self.controls.get(name)
        if c is None:
            return False
        v = self.get(name) + steps * c.step
        if c.kind in ("slider", "int"):
            v = min(max(v, c.lo), c.hi)
        if name == "step":
            v = (self.p.step + steps) % self.model.n_steps
        ok = self.set(name, v, dragging=True) if c.kind == "slider" else self.set(name, v)
        if c.kind == "slider":
            self.dragging = False
            self._settle_until = time.monotonic() + SETTLE_S
        return ok

    def cycle(self, name: str, direction: int = 1) -> bool:
        c = self.controls[name]
        if name == "camera":
            return self.set(name, (self.p.camera + direction) % len(c.options))
        i = c.options.index(self.get(name))
        return self.set(name, c.options[(i + direction) % len(c.options)])

    def press(self, name: str) -> bool:
        """The buttons: ``play`` (start/stop stepping through the load steps), ``save`` (the
        edited scene as TOML at :attr:`save_path`), ``screenshot`` (:attr:`screenshot_path`)."""
        if name == "play":
            self.p.playing = not self.p.playing
            self._last_play = time.monotonic()
            self._dirty = True
        elif name == "save":
            self._note(f"scene saved: {self.save(self.save_path)}")
        elif name == "screenshot":
            self._note(f"screenshot saved: {self.screenshot(self.screenshot_path)}")
        return True

    def tick(self, now: float | None = None) -> bool:
        """Advance the load step while playing; True when the frame must be redrawn."""
        now = time.monotonic() if now is None else now
        if self.p.playing and now - self._last_play >= self.play_interval:
            self._last_play = now
            self.p.step = (self.p.step + 1) % self.model.n_steps
            self._version += 1
            self._dirty = True
        return self.needs_redraw

    def _note(self, text: str) -> None:
        if not self.messages or self.messages[-1] != text:
            self.messages.append(text)
        del self.messages[:-4]
        self._dirty = True

    # ---- state ---------------------------------------------------------------------------------
    @property
    def quality(self) -> str:
        """"fast" while a control is dragged, the steps play or a wheel/key burst settles."""
        busy = self.dragging or self.p.playing or time.monotonic() < self._settle_until
        return "fast" if busy else "full"

    @property
    def needs_redraw(self) -> bool:
        """Something changed since the last frame, or the last frame awaits its refinement."""
        return self._dirty or (self._frame_quality == "fast" and self.quality == "full")

    @property
    def busy(self) -> bool:
        """Draw again at once (a changed frame, or a fast frame while interacting)."""
        return self.needs_redraw and self.quality == "fast" or self._dirty

    def log_state(self) -> str:
        """One line per drawn frame (the window's --log-frames, tests)."""
        return (f"frame step={self.p.step} quality={self._frame_quality} version={self._version} "
                f"size={self._frame.shape[1]}x{self._frame.shape[0]} " +
                " ".join(f"{k}={v}" for k, v in self.state_summary().items()))

    @property
    def settle_seconds(self) -> float:
        return max(0.0, self._settle_until - time.monotonic())

    # ---- rendering ---------------------------------------------------------------------------
    def _layout(self) -> dict:
        W, H = self.size
        pw = min(300, max(200, W // 4))
        lw = W - pw
        cams = self.scene.cameras
        n = len(cams)
        box_w, top = lw // n, 18
        box_h = max(40, int((H - top) * 0.6))
        tiles = []
        for i, c in enumerate(cams):
            s = min(box_w / c.width, box_h / c.height)
            tw, th = max(1, int(c.width * s)), max(1, int(c.height * s))
            tiles.append((i * box_w + (box_w - tw) // 2, top, tw, th))
        th = max(t[3] for t in tiles)
        by = top + th + 6
        rw = int(lw * 0.5)
        return {"tiles": tiles, "rig": (0, by, rw, H - by), "info": (rw, by, lw - rw, H - by), "panel": (lw, 0, pw, H)}

    def tile_scale(self, i: int) -> float:
        """Tile width over camera ``i``'s width."""
        return self._layout()["tiles"][i][2] / self.scene.cameras[i].width

    def drag_scale(self) -> float:
        w = self.drag_width or self._layout()["tiles"][0][2]
        return min(1.0, w / self.scene.cameras[0].width)

    def _render_options(self, quality: str) -> dict:
        if quality == "full":
            return {}
        interp = self.scene.render.interpolation
        return {"mode": "fast", "samples_per_pixel": 1,
                **({"interpolation": "bspline3"} if interp == "procedural" else {})}

    def _with_scene(self, scene: Scene, fn):
        r = self.renderer
        r.scene = scene
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                out = fn(r)
            for w in caught:
                self._note(str(w.message).split(" — ")[0][:160])
            return out
        finally:
            r.scene = self.scene

    @_gl
    def results(self, quality: str | None = None):
        """The cameras' :class:`~glsim.render.Result` at ``quality`` ("full": the scene's size and
        mode; "fast": fast mode at the drag size), rendered if out of date."""
        quality = quality or self.quality
        if self._results is not None and self._results[:2] == (self._version, quality):
            return self._results[2]
        t0 = time.perf_counter()
        scene = self.scene if quality == "full" else scaled_scene(self.scene, self.drag_scale())
        opts = self._render_options(quality)
        step = self.p.step
        res = self._with_scene(scene, lambda r: [r.render(i, step, **opts) for i in range(len(scene.cameras))])
        self.timings[f"render_{quality}"] = time.perf_counter() - t0
        self._results = (self._version, quality, res)
        return res

    @_gl
    def truths(self, quality: str | None = None):
        """Ground truth of each camera at its size on screen (the overlays' resolution)."""
        quality = quality or self.quality
        scale = min(self.tile_scale(0), 1.0)
        if quality == "fast":   # coarse overlays while dragging: at most DRAG_TRUTH_PX pixels a camera
            c = self.scene.cameras[0]
            scale = min(scale, self.drag_scale(), math.sqrt(DRAG_TRUTH_PX / (c.width * c.height)))
        if self._truths is not None and self._truths[:3] == (self._version, quality, scale):
            return self._truths[3]
        t0 = time.perf_counter()
        scene = scaled_scene(self.scene, scale)
        opts = self._render_options(quality)
        step = self.p.step
        tr = self._with_scene(scene, lambda r: [r.render(i, step, truth=True, **opts).truth
                                                for i in range(len(scene.cameras))])
        self.timings[f"truth_{quality}"] = time.perf_counter() - t0
        self._truths = (self._version, quality, scale, tr, scene)
        return tr

    def truth_scene(self) -> Scene:
        """The (scaled) scene the last :meth:`truths` were rendered with."""
        return self._truths[4]

    # ---- overlays ----------------------------------------------------------------------------
    def overlay_data(self, i: int, quality: str | None = None) -> dict:
        """What the overlays of camera ``i`` show, at the truth's resolution (masks, maps) or
        the image's (clipped pixels, speckle), as plain arrays and numbers."""
        quality = quality or self.quality
        on = self.p.overlays
        scene = self.scene
        out: dict = {}
        res = self.results(quality)
        img = res[i].image
        deformed = self.mesh.deformed(self.p.step)
        if on["clipped"]:
            out["above"], out["below"] = ov.clipped(img, res[i].coverage)
            out["specimen_px"] = int(np.count_nonzero(res[i].coverage))
        if on["range"]:
            out["range_px"] = ov.displacement_range(scene.cameras[i], self.mesh.nodes, deformed)
        if on["speckle"] and quality == "full":
            key = (self._version, i)
            if key not in self._speckle_cache:
                self._speckle_cache = {key: ov.speckle_size(img, res[i].coverage)}
            out["speckle"] = self._speckle_cache[key]
        if any(on[k] for k in TRUTH_OVERLAYS):
            tr = self.truths(quality)
            tscene = self.truth_scene()
            cams = tscene.cameras
            if on["displacement"]:
                out["displacement"] = ov.displacement(tr[i], self.p.component)
                out["mm_per_px"] = ov.mm_per_px(scene.cameras[i], deformed)
            if on["overlap"] and len(cams) > 1:
                j = (i + 1) % len(cams) if i == 0 else 0
                out["overlap"] = ov.overlap(tr[i], tr[j], cams[i], cams[j], cams[0])
                out["covered"] = tr[i].mask
            if on["coc"] and scene.optics is not None:
                out["coc"] = ov.coc_map(tr[i], cams[i], cams[0], scene.optics)
                out["dof"] = ov.dof_limits(scene.optics)
                with np.errstate(invalid="ignore"):
                    Z = ov.depth(tr[i], cams[i], cams[0])
                out["depth"] = (float(np.nanmin(Z)), float(np.nanmax(Z))) if np.isfinite(Z).any() else None
        return out

    def _draw_tile(self, frame, i: int, box, res, data: dict) -> None:
        x, y, w, h = box
        cam = self.scene.cameras[i]
        grey = display_grey(res.image, cam.bit_depth)
        if grey.shape != (h, w):
            interp = cv2.INTER_AREA if grey.shape[1] > w else cv2.INTER_LINEAR
            grey = cv2.resize(grey, (w, h), interpolation=interp)
        tile = np.repeat(grey[..., None], 3, axis=2).astype(np.float32)

        def fit(a, interp=cv2.INTER_NEAREST):
            a = np.asarray(a)
            if a.shape[:2] == (h, w):
                return a
            return cv2.resize(a.astype(np.float32) if a.dtype == bool else a, (w, h), interpolation=interp)

        def blend(mask, colour, alpha):
            m = fit(mask.astype(np.uint8)).astype(bool)
            tile[m] = (1 - alpha) * tile[m] + alpha * np.asarray(colour, np.float32)

        if "displacement" in data:
            d = data["displacement"]
            lo, hi = self._disp_range(d)
            rgb = fit(ov.colour_map(d, lo, hi))
            m = fit(np.isfinite(d).astype(np.uint8)).astype(bool)
            tile[m] = 0.35 * tile[m] + 0.65 * rgb[m]
        if "coc" in data:
            c = data["coc"]
            limit = self.scene.optics.coc_px
            rgb = fit(ov.colour_map(c, 0.0, self._coc_hi(c)))
            m = fit(np.isfinite(c).astype(np.uint8)).astype(bool)
            tile[m] = 0.35 * tile[m] + 0.65 * rgb[m]
            with np.errstate(invalid="ignore"):
                blurred = fit((c > limit).astype(np.uint8))
            edge = cv2.morphologyEx(blurred, cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)).astype(bool) & m
            tile[edge] = (255, 255, 255)
        if "overlap" in data:
            blend(data["overlap"], (60, 220, 90), 0.35)
            blend(data["covered"] & ~data["overlap"], (230, 60, 200), 0.55)
        if "above" in data:
            for mask, colour in ((data["above"], (255, 30, 30)), (data["below"], (40, 80, 255))):
                if mask.any():
                    m = mask if mask.shape == (h, w) else cv2.resize(mask.astype(np.uint8), (w, h),
                                                                     interpolation=cv2.INTER_AREA) > 0
                    if mask.shape != (h, w):   # keep isolated clipped pixels visible when shrunk
                        m |= cv2.resize(cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)), (w, h),
                                        interpolation=cv2.INTER_NEAREST) > 0
                    tile[m] = colour
        out = np.clip(tile, 0, 255).astype(np.uint8)
        if self.p.overlays["edges"]:
            s = w / cam.width
            lines = ov.edge_polylines(cam, self.mesh.deformed(self.p.step), self.mesh.quads)
            pts = [np.rint(((ln + 0.5) * s - 0.5) * 16).astype(np.int32) for ln in lines]
            if pts:
                cv2.polylines(out, pts, False, (255, 220, 40), 1, cv2.LINE_AA, shift=4)
        sp = data.get("speckle")
        if sp is not None:
            s = w / cam.width
            r0, r1, c0, c1 = sp["region"]
            cv2.rectangle(out, (int(c0 * s), int(r0 * s)), (int(c1 * s), int(r1 * s)), (80, 230, 255), 1)
        frame[y:y + h, x:x + w] = out
        colour = draw.CAMERA_COLOURS[i % len(draw.CAMERA_COLOURS)]
        if i == self.p.camera:
            cv2.rectangle(frame, (x - 2, y - 2), (x + w + 1, y + h + 1), colour, 2)
        label = f"{cam.name}  {cam.width}x{cam.height}  {res.options.mode}"
        if self.show_timings:
            label += f"  {res.seconds * 1e3:.0f} ms"
        if res.camera.size != cam.size:
            label += f"  (preview {res.camera.width}x{res.camera.height})"
        draw.text(frame, label, x + 2, y - 5, colour, 0.4)

    @staticmethod
    def _disp_range(d):
        if not np.isfinite(d).any():
            return 0.0, 1.0
        lo, hi = float(np.nanmin(d)), float(np.nanmax(d))
        if lo >= 0 or hi <= 0:
            lo = min(lo, 0.0)
        return (lo, hi) if hi > lo else (lo, lo + 1e-3)

    @staticmethod
    def _coc_hi(c):
        m = float(np.nanmax(c)) if np.isfinite(c).any() else 1.0
        return max(m, 1e-3)

    def _info(self, frame, box, data_all, res) -> None:
        x, y, w, h = box
        frame[y:y + h, x:x + w] = (20, 20, 24)
        p, cams = self.p, self.scene.cameras
        ly = y + 16

        def line(s, colour=draw.WHITE, scale=0.42):
            nonlocal ly
            if ly < y + h - 4:
                draw.text(frame, s, x + 8, ly, colour, scale)
            ly += 17

        q = self._frame_quality or self.quality
        t = self.timings.get(f"render_{q}", 0.0)
        line(f"step {p.step}/{self.model.n_steps - 1}   mode {self.scene.render.mode}   "
             f"{'playing' if p.playing else ''}  {'preview (fast)' if q == 'fast' else 'full quality'}" +
             (f" {t * 1e3:.0f} ms" if self.show_timings else ""))
        fx = [n for n, on in (("lighting", self.scene.lighting), ("DOF", self.scene.optics), ("noise", self.scene.noise)) if on]
        line("effects: " + (", ".join(fx) or "none"), draw.GREY)
        if self.show_help:
            for k in ("keys: <- -> step, space play, c camera, m mode, 1 2 3 effects",
                      "d disp. (v component), e edges, o overlap, f CoC, k clipped",
                      "z speckle, g range, [ ] stereo angle, - = distance, , . focal",
                      "n N f-number, w save TOML, p screenshot, r reset view, q quit"):
                line(k, draw.GREY, 0.38)
        for i, (cam, data) in enumerate(zip(cams, data_all)):
            colour = draw.CAMERA_COLOURS[i % len(draw.CAMERA_COLOURS)]
            parts = []
            if "speckle" in data:
                sp = data["speckle"]
                parts.append("speckle: too little specimen" if sp is None else
                             f"speckle {sp['dot_diameter_px']:.2f} px (dots), {sp['speckle_diameter_px']:.2f} px (blobs)")
            elif p.overlays["speckle"]:
                parts.append("speckle: measured after refinement")
            if "range_px" in data:
                lo, hi = data["range_px"]
                parts.append(f"displacement {lo:.2f}-{hi:.2f} px")
            if "above" in data:
                n = max(data["specimen_px"], 1)
                parts.append(f"clipped {100 * data['above'].sum() / n:.2g}% high, {100 * data['below'].sum() / n:.2g}% "
                              "low (of the specimen's pixels)")
            if "coc" in data:
                c = data["coc"]
                near, far = data["dof"]
                cmax = float(np.nanmax(c)) if np.isfinite(c).any() else float("nan")
                dep = data.get("depth")
                parts.append(f"CoC max {cmax:.2f} px; DOF {near:.1f}-{far:.1f} mm" +
                             (f"; surface {dep[0]:.1f}-{dep[1]:.1f} mm" if dep else ""))
            elif p.overlays["coc"]:
                parts.append("CoC: depth of field is off (switch it on)")
            if "overlap" in data:
                cov = data["covered"].sum()
                parts.append(f"seen by both {100 * data['overlap'].sum() / max(cov, 1):.3g}% of specimen px")
            if parts:
                line(f"{cam.name}:", colour)
                for s in parts:
                    line("  " + s, draw.WHITE, 0.4)
        for m in self.messages[-3:]:
            line(m[:110], (255, 180, 120), 0.38)
        # colour bar of the active camera's map
        data = data_all[p.camera]
        bw, bx, by = w - 90, x + 12, y + h - 52
        if "displacement" in data and by > ly:
            lo, hi = self._disp_range(data["displacement"])
            mmpx = data["mm_per_px"]
            draw.colour_bar(frame, bx, by, bw, 12, lo, hi, ov.nice_ticks(lo, hi),
                            f"{cams[p.camera].name}: displacement {p.component} (mm; px at {mmpx:.3g} mm/px)",
                            (1 / mmpx, "px"))
        elif "coc" in data and by > ly:
            hi = self._coc_hi(data["coc"])
            draw.colour_bar(frame, bx, by, bw, 12, 0.0, hi, ov.nice_ticks(0.0, hi),
                            f"{cams[p.camera].name}: circle of confusion (px); white line: CoC = {self.scene.optics.coc_px:g} px")

    def _panel(self, frame, box) -> None:
        x, y, w, h = box
        frame[y:y + h, x:x + w] = (36, 36, 42)
        draw.text(frame, "controls (drag a value, click -/+)", x + 8, y + 14, draw.GREY, 0.38)
        ry = y + 22
        rows = list(self.controls.values())
        fit = max(1, (h - 22) // ROW)
        self._panel_offset = min(max(self._panel_offset, 0), max(0, len(rows) - fit))
        if len(rows) > fit:
            draw.text(frame, f"wheel: more ({self._panel_offset + 1}-{min(len(rows), self._panel_offset + fit)} "
                      f"of {len(rows)})", x + w - 120, y + h - 4, draw.GREY, 0.34)
            fit -= 1
        self._hits.append(((x, y, w, h), ("panel", None)))
        for c in rows[self._panel_offset:self._panel_offset + fit]:
            self._hits.append(((x, ry, w, ROW), ("control", c.name)))
            if c.kind == "toggle":
                on = self.get(c.name)
                cv2.rectangle(frame, (x + 8, ry + 4), (x + 19, ry + 15), draw.WHITE, 1)
                if on:
                    cv2.rectangle(frame, (x + 10, ry + 6), (x + 17, ry + 13), (120, 220, 120), -1)
                draw.text(frame, ("overlay: " if c.name.startswith("overlay:") else "") + c.label, x + 26, ry + 14,
                          draw.WHITE, 0.4)
            elif c.kind == "button":
                cv2.rectangle(frame, (x + 8, ry + 2), (x + w - 8, ry + ROW - 2), (70, 70, 80), -1)
                label = ("stop" if self.p.playing else "play") + " load steps" if c.name == "play" else c.label
                draw.text(frame, label, x + 14, ry + 14, draw.WHITE, 0.4)
            else:
                v = self.get(c.name)
                if c.kind == "choice":
                    vs = c.options[v] if c.name == "camera" else str(v)
                elif c.kind == "int":
                    vs = str(v)
                else:
                    vs = f"{v:.4g}{c.unit and ' ' + c.unit}"
                draw.text(frame, c.label, x + 8, ry + 13, draw.WHITE, 0.4)
                draw.text(frame, vs, x + w - 44 - draw.text_width(vs, 0.4), ry + 13, (255, 230, 150), 0.4)
                if c.kind in ("slider", "int"):
                    frac = (float(v) - c.lo) / (c.hi - c.lo) if c.hi > c.lo else 0.0
                    x0, x1 = x + 8, x + w - 44
                    cv2.line(frame, (x0, ry + 17), (x1, ry + 17), (80, 80, 90), 2)
                    cv2.line(frame, (x0, ry + 17), (x0 + int(np.clip(frac, 0, 1) * (x1 - x0)), ry + 17), (120, 170, 255), 2)
                draw.text(frame, "-", x + w - 34, ry + 14, draw.WHITE, 0.5)
                draw.text(frame, "+", x + w - 18, ry + 14, draw.WHITE, 0.5)
            ry += ROW

    @_gl
    def frame(self, quality: str | None = None) -> np.ndarray:
        """The preview as an H×W×3 uint8 RGB frame (rendering what is out of date)."""
        quality = quality or self.quality
        t0 = time.perf_counter()
        W, H = self.size
        frame = np.full((H, W, 3), draw.BACKGROUND, np.uint8)
        self._hits = []
        lay = self._layout()
        res = self.results(quality)
        data_all = [self.overlay_data(i, quality) for i in range(len(res))]
        for i, box in enumerate(lay["tiles"]):
            self._draw_tile(frame, i, box, res[i], data_all[i])
            self._hits.append((box, ("tile", i)))
        x, y, w, h = lay["rig"]
        if w > 10 and h > 10:
            rig = draw.rig_view((w, h), self.orbit, self.scene.cameras, self.p.camera,
                                self.mesh.deformed(self.p.step), self.mesh.quads,
                                self.scene.lighting.lights if self.scene.lighting else (),
                                target=self.model.rig.target)
            frame[y:y + h, x:x + w] = rig
            self._hits.append((lay["rig"], ("rig", None)))
        self._frame_quality = quality
        self._info(frame, lay["info"], data_all, res)
        self._panel(frame, lay["panel"])
        self._frame = frame
        self._dirty = False
        self.timings[f"frame_{quality}"] = time.perf_counter() - t0
        return frame

    def refine(self) -> np.ndarray:
        """The full-quality frame (ends a drag)."""
        self.dragging = False
        self._settle_until = 0.0
        return self.frame("full")

    def camera_image(self, i: int, quality: str = "full") -> np.ndarray:
        """Camera ``i``'s image as rendered for the preview (float32, the renderer's grey)."""
        return self.results(quality)[i].image

    def tile(self, i: int) -> np.ndarray:
        """The pixels of camera ``i``'s tile in the last frame."""
        x, y, w, h = self._layout()["tiles"][i]
        return self._frame[y:y + h, x:x + w]

    @_gl
    def gl_info(self) -> dict:
        """`glsim info`'s fields for the preview's GL context."""
        from glsim.backends.gl.context import info
        return info(self.ctx)

    def state_summary(self) -> dict:
        """The live state in a few words (the window's frame log, tests)."""
        p = self.p
        return {"camera": p.camera, "mode": self.scene.render.mode, "lighting": p.lighting, "dof": p.dof,
                "noise": p.noise, "overlays": ",".join(k for k, on in p.overlays.items() if on) or "-"}

    # ---- saving ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """The edited scene as TOML (``load_scene`` reads it back and renders the same images)."""
        return save_scene(self.scene, path, self._tmp)

    @_gl
    def screenshot(self, path: str | Path) -> Path:
        """The full-quality frame as PNG."""
        return draw.save_png(path, self.refine)

    # ---- events (jupyter_rfb's event dicts; the window translates its own into these) ---------
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


def draw_once(scene: Scene | str | Path, size=(1280, 800), step: int | None = None, overlays=()) -> np.ndarray:
    """The full-quality preview frame of ``scene`` (what the window shows first)."""
    with Preview(scene, size=size) as pv:
        if step is not None:
            pv.set("step", step)
        for name in overlays:
            pv.set(f"overlay:{name}", True)
        return pv.refine()
