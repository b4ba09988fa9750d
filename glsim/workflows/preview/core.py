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

import numpy as np

from glsim.errors import GlsimError
from glsim.render import Renderer
from glsim.scene import Scene, load_scene
from glsim.io.fe import specimen_mesh
from glsim.workflows.preview import draw, overlays as ov
from glsim.workflows.preview.controls import OVERLAYS, Control, Model, moved_light
from glsim.workflows.preview.events import Events
from glsim.workflows.preview.layout import frame_layout, scaled_scene
from glsim.workflows.preview.panes import Panes
from glsim.workflows.preview.sceneio import pinned_speckle, reference_inputs, save_scene

TRUTH_OVERLAYS = ("displacement", "overlap", "coc")
DRAG_TRUTH_PX = 60_000  # truth pixels per camera while dragging
SETTLE_S = 0.25     # refine this long after the last wheel or key step


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


class Preview(Panes, Events):
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
        return frame_layout(self.size, self.scene.cameras)

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
        res = self._with_scene(scene, lambda r: list(r.render_many({"camera": i, "step": step, **opts}
                                                                  for i in range(len(scene.cameras)))))
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
        tr = self._with_scene(scene, lambda r: [x.truth for x in r.render_many(
            {"camera": i, "step": step, "truth": True, **opts} for i in range(len(scene.cameras)))])
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
                "noise": p.noise, "psf": p.psf, "vignetting": p.vignetting, "fpn": p.fpn, "motion": p.motion,
                "overlays": ",".join(k for k, on in p.overlays.items() if on) or "-"}

    # ---- saving ------------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """The edited scene as TOML (``load_scene`` reads it back and renders the same images)."""
        return save_scene(self.scene, path, self._tmp)

    @_gl
    def screenshot(self, path: str | Path) -> Path:
        """The full-quality frame as PNG."""
        return draw.save_png(path, self.refine)


def draw_once(scene: Scene | str | Path, size=(1280, 800), step: int | None = None, overlays=()) -> np.ndarray:
    """The full-quality preview frame of ``scene`` (what the window shows first)."""
    with Preview(scene, size=size) as pv:
        if step is not None:
            pv.set("step", step)
        for name in overlays:
            pv.set(f"overlay:{name}", True)
        return pv.refine()
