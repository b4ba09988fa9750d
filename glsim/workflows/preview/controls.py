"""The preview's controls: each one a named live parameter with its range, and how the edited
scene is made from the loaded one and the parameters (never cumulatively: setting every
parameter back gives the loaded scene again)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from glsim.errors import SceneError
from glsim.scene import MODES, Light, Scene, demo_effects
from glsim.scene import Exposure, Psf, Sensor, Vignetting
from glsim.scene.camera import Camera, rodrigues
from glsim.scene.tables import as_tuple

OVERLAYS = ("displacement", "edges", "overlap", "coc", "clipped", "speckle", "range")
COMPONENTS = ("magnitude", "x", "y", "z")


@dataclass(frozen=True)
class Control:
    """``kind``: "slider" (lo…hi, ``step`` per key press), "int", "choice" (``options``),
    "toggle", or "button". ``scene``: True when it changes the rendered scene (False: what is
    shown only)."""
    name: str
    label: str
    kind: str
    lo: float = 0.0
    hi: float = 1.0
    step: float = 1.0
    options: tuple = ()
    unit: str = ""
    scene: bool = True


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``a`` to direction ``b``."""
    a, b = _unit(a), _unit(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    if s < 1e-15:
        return np.eye(3)
    return rodrigues(axis / s * math.atan2(s, float(a @ b)))


@dataclass(frozen=True, eq=False)
class Rig:
    """The loaded cameras and the geometry the pose controls turn them about: ``target`` (where
    the optical axes of cameras 1 and 2 meet, else the specimen's centre), ``up`` (the axis the
    stereo angle turns about), the stereo angle (deg) and the mean distance to the target (mm)."""
    cameras: tuple[Camera, ...]
    target: np.ndarray
    up: np.ndarray
    angle: float
    distance: float
    signs: np.ndarray

    @classmethod
    def of(cls, cameras: tuple[Camera, ...], nodes: np.ndarray) -> "Rig":
        centre = nodes.mean(axis=0)
        target = centre
        z = [c.rotation[2] for c in cameras]
        C = [c.center for c in cameras]
        angle = 0.0
        up = -cameras[0].rotation[1]
        if len(cameras) >= 2:
            angle = math.degrees(math.acos(float(np.clip(z[0] @ z[1], -1, 1))))
            n = np.cross(z[0], z[1])
            if np.linalg.norm(n) > 1e-6:
                up = _unit(n) * (1 if n @ up >= 0 else -1)
                # closest points of the two optical axes
                w = C[0] - C[1]
                a, b, c, d, e = z[0] @ z[0], z[0] @ z[1], z[1] @ z[1], z[0] @ w, z[1] @ w
                den = a * c - b * b
                s, t = (b * e - c * d) / den, (a * e - b * d) / den
                if s > 0 and t > 0:
                    target = (C[0] + s * z[0] + C[1] + t * z[1]) / 2
        p = [ci - target for ci in C]
        flat = [pi - (pi @ up) * up for pi in p]
        bis = np.mean(flat, axis=0)
        bis = _unit(bis) if np.linalg.norm(bis) > 1e-9 else _unit(flat[0])
        signs = np.array([np.sign(np.cross(up, fi) @ (fi - (fi @ bis) * bis)) for fi in flat])
        dist = float(np.mean([np.linalg.norm(pi) for pi in p]))
        return cls(tuple(cameras), target, up, angle, dist, signs)

    def posed(self, angle: float, distance: float, target_offset) -> tuple[Camera, ...]:
        """The cameras turned to stereo ``angle`` (deg) about ``up`` through the target, moved
        to ``distance`` (mm, mean, along their lines to the target), then aimed at the target
        moved by ``target_offset`` (mm, world); the loaded cameras when nothing changed."""
        off = np.asarray(target_offset, float)
        if angle == self.angle and distance == self.distance and not off.any():
            return self.cameras
        out = []
        for cam, s in zip(self.cameras, self.signs):
            R, C = cam.rotation, cam.center
            if angle != self.angle and s != 0:
                Q = rodrigues(self.up * math.radians(s * (angle - self.angle) / 2))
                C = self.target + Q @ (C - self.target)
                R = R @ Q.T
            if distance != self.distance:
                C = self.target + (C - self.target) * (distance / self.distance)
            if off.any():
                Q = _rotation_between(self.target - C, self.target + off - C)
                R = R @ Q.T
            out.append(dataclasses.replace(cam, R=as_tuple(R), t=as_tuple(-R @ C)))
        return tuple(out)


@dataclass
class Params:
    """The live parameters (what the controls set)."""
    step: int = 0
    camera: int = 0
    mode: str = "exact"
    lighting: bool = False
    dof: bool = False
    noise: bool = False
    psf: bool = False
    vignetting: bool = False
    fpn: bool = False         # [sensor]: fixed-pattern noise (and the scene's fill factor)
    motion: bool = False      # [exposure]: motion over the exposure
    stereo_angle: float = 0.0
    distance: float = 0.0
    target_x: float = 0.0
    target_y: float = 0.0
    target_z: float = 0.0
    focal_length: float = 0.0
    f_number: float = 8.0
    focus_distance: float = 0.0
    ambient: float = 0.0
    light: int = 0
    light_intensity: float = 0.0
    light_x: float = 0.0
    light_y: float = 0.0
    light_z: float = 0.0
    noise_sigma: float = 0.0
    psf_sigma: float = 1.0        # px, a Gaussian PSF's
    vignetting_a1: float = 0.0    # the radial fall-off's first coefficient
    prnu: float = 0.0             # %
    dsnu: float = 0.0             # DN
    exposure_time: float = 0.0    # s
    exposure_samples: int = 1
    speckle_size: float = 5.0
    speckle_seed: int = 0
    overlays: dict = field(default_factory=lambda: {k: False for k in OVERLAYS})
    component: str = "magnitude"
    playing: bool = False


class Model:
    """The loaded scene, its rig, the effects to switch on where the scene has none, and the
    controls; :meth:`scene` makes the edited scene from :class:`Params`."""

    def __init__(self, scene: Scene, nodes: np.ndarray, n_steps: int):
        self.base = scene
        self.rig = Rig.of(scene.cameras, nodes)
        self.n_steps = n_steps
        defaults = demo_effects(scene)
        self.lighting = scene.lighting or defaults.lighting
        if not self.lighting.lights:
            self.lighting = dataclasses.replace(self.lighting, lights=defaults.lighting.lights)
        pitch = scene.optics.pixel_pitch if scene.optics else defaults.optics.pixel_pitch
        self.pitch = pitch
        cam0 = scene.cameras[0]
        self.base_focal = cam0.fx * pitch
        self.optics = scene.optics or dataclasses.replace(
            defaults.optics, focal_length=self.base_focal, focus_distance=self.rig.distance)
        self.noise = scene.noise or defaults.noise
        # the camera effects a toggle switches on where the scene has none (docs/camera.md,
        # docs/motion.md): a 1 px Gaussian PSF, natural vignetting, 1 % PRNU and 1 DN DSNU, a
        # 0.2 s exposure of 4 samples around the step (steps 1 s apart)
        self.camera_effects = {"psf": scene.psf or Psf(kind="gaussian", sigma=1.0),
                               "vignetting": scene.vignetting or Vignetting(natural=True),
                               "fpn": scene.sensor or Sensor(prnu=1.0, dsnu=1.0),
                               "motion": scene.exposure or Exposure(time=0.2, samples=4)}

    def params(self) -> Params:
        s, o, lit = self.base, self.optics, self.lighting
        light = lit.lights[0]
        return Params(
            mode=s.render.mode, lighting=s.lighting is not None, dof=s.optics is not None,
            noise=s.noise is not None, psf=s.psf is not None, vignetting=s.vignetting is not None,
            fpn=s.sensor is not None, motion=s.exposure is not None, stereo_angle=self.rig.angle, distance=self.rig.distance,
            focal_length=self.base_focal, f_number=o.f_number, focus_distance=o.focus_distance,
            ambient=lit.ambient, light_intensity=light.intensity, light_x=light.position[0],
            light_y=light.position[1], light_z=light.position[2],
            noise_sigma=self.noise.sigma, speckle_size=s.speckle.dot_diameter_px, speckle_seed=s.speckle.seed,
            **self._effect_values())

    def _effect_values(self) -> dict:
        """The camera effects' values the sliders start from: the scene's tables, else the defaults."""
        fx = self.camera_effects
        psf, vig, sensor, ex = fx["psf"], fx["vignetting"], fx["fpn"], fx["motion"]
        return {"psf_sigma": psf.sigma if psf.kind == "gaussian" else 1.0,
                "vignetting_a1": vig.radial[0] if vig.radial else 0.0, "prnu": sensor.prnu, "dsnu": sensor.dsnu,
                "exposure_time": ex.time, "exposure_samples": ex.samples}

    def controls(self) -> list[Control]:
        r, d = self.rig, self.rig.distance
        n_lights = len(self.lighting.lights)
        out = [Control("step", "load step", "int", 0, self.n_steps - 1, 1),
               Control("play", "play steps", "button"),
               Control("camera", "camera", "choice", options=tuple(c.name for c in self.base.cameras), scene=False),
               Control("mode", "accuracy mode", "choice", options=MODES),
               Control("lighting", "lighting", "toggle"),
               Control("dof", "depth of field", "toggle"),
               Control("noise", "noise", "toggle"),
               Control("psf", "lens PSF", "toggle"),
               Control("vignetting", "vignetting", "toggle"),
               Control("fpn", "fixed-pattern noise", "toggle"),
               Control("motion", "motion over the exposure", "toggle")]
        if len(self.base.cameras) >= 2:
            out.append(Control("stereo_angle", "stereo angle", "slider", max(0.0, r.angle - 30), min(120.0, r.angle + 30),
                               1.0, unit="°"))
        out += [Control("distance", "distance", "slider", 0.5 * d, 2.0 * d, d / 60, unit="mm"),
                Control("target_x", "look-at x", "slider", -0.2 * d, 0.2 * d, d / 300, unit="mm"),
                Control("target_y", "look-at y", "slider", -0.2 * d, 0.2 * d, d / 300, unit="mm"),
                Control("target_z", "look-at z", "slider", -0.2 * d, 0.2 * d, d / 300, unit="mm"),
                Control("focal_length", "focal length", "slider", 0.5 * self.base_focal, 2.0 * self.base_focal,
                        self.base_focal / 60, unit="mm"),
                Control("f_number", "f-number", "slider", 1.4, 22.0, 0.2),
                Control("focus_distance", "focus distance", "slider", 0.5 * d, 2.0 * d, d / 120, unit="mm"),
                Control("ambient", "ambient I_a", "slider", -0.5, 0.5, 0.01)]
        if n_lights > 1:
            out.append(Control("light", "light", "int", 0, n_lights - 1, 1))
        out += [Control("light_intensity", "light intensity", "slider", 0.0, 1.5, 0.02),
                Control("light_x", "light x", "slider", -d, d, d / 60, unit="mm"),
                Control("light_y", "light y", "slider", -d, d, d / 60, unit="mm"),
                Control("light_z", "light z", "slider", -d, 2 * d, d / 60, unit="mm"),
                Control("noise_sigma", "noise σ", "slider", 0.0, 10.0, 0.1, unit="%")]
        if self.camera_effects["psf"].kind == "gaussian":   # (an Airy or measured PSF has no σ)
            out.append(Control("psf_sigma", "PSF σ", "slider", 0.2, 5.0, 0.05, unit="px"))
        T = self.camera_effects["motion"].time or 0.2
        out += [Control("vignetting_a1", "vignetting a1", "slider", -0.5, 0.5, 0.01),
                Control("prnu", "PRNU", "slider", 0.0, 5.0, 0.1, unit="%"),
                Control("dsnu", "DSNU", "slider", 0.0, 10.0, 0.2, unit="DN"),
                Control("exposure_time", "exposure time", "slider", 0.0, 4 * T, T / 20, unit="s"),
                Control("exposure_samples", "exposure samples", "int", 1, 32, 1),
                Control("speckle_size", "speckle size", "slider", 2.0, 15.0, 0.25, unit="px"),
                Control("speckle_seed", "speckle seed", "int", 0, 999, 1)]
        out += [Control(f"overlay:{k}", label, "toggle", scene=False) for k, label in (
            ("displacement", "displacement"), ("edges", "element edges"), ("overlap", "stereo overlap"),
            ("coc", "CoC / depth of field"), ("clipped", "clipped pixels"), ("speckle", "speckle size"),
            ("range", "displacement range"))]
        out += [Control("component", "component", "choice", options=COMPONENTS, scene=False),
                Control("save", "save scene TOML", "button", scene=False),
                Control("screenshot", "save screenshot PNG", "button", scene=False)]
        return out

    def scene(self, p: Params, lights: list[Light]) -> Scene:
        """The edited scene (poses, lens, effects, speckle) — before the speckle is pinned."""
        s = self.base
        cams = self.rig.posed(p.stereo_angle, p.distance, (p.target_x, p.target_y, p.target_z))
        if p.focal_length != self.base_focal:
            k = p.focal_length / self.base_focal
            cams = tuple(dataclasses.replace(c, fx=c.fx * k, fy=c.fy * k) for c in cams)
        # every effect's values are checked, also while it is switched off
        lighting = dataclasses.replace(self.lighting, ambient=p.ambient, lights=tuple(lights))
        optics = dataclasses.replace(self.optics, focal_length=p.focal_length, f_number=p.f_number,
                                     focus_distance=p.focus_distance)
        noise = dataclasses.replace(self.noise, sigma=p.noise_sigma)
        lighting, optics, noise = (x if on else None for x, on in
                                   ((lighting, p.lighting), (optics, p.dof), (noise, p.noise)))
        speckle = s.speckle
        if not speckle.image and (p.speckle_size != speckle.dot_diameter_px or p.speckle_seed != speckle.seed):
            speckle = dataclasses.replace(speckle, dot_diameter_px=p.speckle_size,
                                          edge_px=min(speckle.edge_px, p.speckle_size), seed=p.speckle_seed)
        render = s.render if p.mode == s.render.mode else dataclasses.replace(s.render, mode=p.mode)
        fx = self.camera_effects
        vig = fx["vignetting"]
        values = {"psf": dataclasses.replace(fx["psf"], sigma=p.psf_sigma) if fx["psf"].kind == "gaussian" else fx["psf"],
                  "vignetting": dataclasses.replace(vig, radial=(p.vignetting_a1, *vig.radial[1:]))
                  if p.vignetting_a1 or vig.radial else vig,
                  "fpn": dataclasses.replace(fx["fpn"], prnu=p.prnu, dsnu=p.dsnu),
                  "motion": dataclasses.replace(fx["motion"], time=p.exposure_time, samples=p.exposure_samples)}
        on = {k: v if getattr(p, k) else None for k, v in values.items()}
        return dataclasses.replace(s, cameras=cams, lighting=lighting, optics=optics, noise=noise,
                                   speckle=speckle, render=render, psf=on["psf"], vignetting=on["vignetting"],
                                   sensor=on["fpn"], exposure=on["motion"])


def moved_light(light: Light, position, intensity: float, target: np.ndarray) -> Light:
    """``light`` at ``position`` with ``intensity``; a spotlight keeps aiming at the point of its
    axis nearest ``target``."""
    pos = np.asarray(position, float)
    direction = light.direction
    if direction is not None and tuple(pos) != tuple(light.position):
        p0, d = np.asarray(light.position, float), _unit(np.asarray(direction, float))
        aim = p0 + max(float((target - p0) @ d), 1.0) * d
        if np.linalg.norm(aim - pos) > 0:
            direction = tuple(float(v) for v in aim - pos)
    try:
        return dataclasses.replace(light, position=tuple(float(v) for v in pos), intensity=float(intensity),
                                   direction=direction)
    except SceneError as exc:
        raise SceneError(f"lighting.lights.{exc.key}", str(exc)) from None
