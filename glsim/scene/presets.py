"""Built-in scenes: the paper's stereo rig and bulge test, and its effects (Tables 1–3)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from glsim.scene.camera import Camera, Distortion, look_at
from glsim.scene.model import Bulge, Render, Scene, Specimen
from glsim.scene.optional import Light, Lighting, Noise, Optics
from glsim.scene.tables import as_tuple

def stereo_rig(size=(1624, 1234), fx=6818.0, distance=600.0, stereo_angle=30.0,
               distortion: Distortion = Distortion(), bit_depth: int = 8) -> tuple[Camera, Camera]:
    """Two identical cameras converging by ``stereo_angle`` (deg) on a point ``distance`` mm in
    front of camera 0, which is the world frame. The default is Table 2/3: 30 mm lenses with
    4.4 µm pixels (fx = 6818 px), 1624×1234 px, ≈ 0.088 mm/px at 600 mm."""
    W, H = size
    half = math.radians(stereo_angle / 2)
    target = np.array([0.0, 0.0, distance])
    # Camera 0 at the origin; camera 1 mirrored about the bisector plane of the rig.
    eye2 = np.array([2 * distance * math.sin(half) * math.cos(half),
                     0.0, 2 * distance * math.sin(half) ** 2])
    R2, t2 = look_at(eye2, target, np.array([0.0, -1.0, 0.0]))
    common = dict(size=(W, H), fx=fx, fy=fx, cx=(W - 1) / 2, cy=(H - 1) / 2,
                  distortion=distortion, bit_depth=bit_depth)
    return Camera(name="cam0", **common), Camera(name="cam1", R=as_tuple(R2), t=as_tuple(t2), **common)


def bulge_scene(size=(1624, 1234), steps: int = 3, **render) -> Scene:
    """The paper's bulge test (Tables 2–3): R = 50 mm plate, 5 mm bulge, 30° stereo rig.

    The plate faces the bisector of the two optical axes, 600 mm from camera 0, and bulges
    towards the cameras.
    """
    cam0, cam1 = stereo_rig(size=size, fx=6818.0 * size[0] / 1624)
    half = math.radians(15.0)
    # The plate's local −z (its bulge direction) points along the rig's bisector, to the cameras.
    Rp = np.array([[math.cos(half), 0, -math.sin(half)], [0, 1, 0], [math.sin(half), 0, math.cos(half)]])
    specimen = Specimen(bulge=Bulge(steps=steps), R=as_tuple(Rp), t=(0.0, 0.0, 600.0))
    return Scene(cameras=(cam0, cam1), specimen=specimen, render=Render(**render))


def demo_effects(scene: Scene) -> Scene:
    """``scene`` lit, slightly defocused and noisy, as in the paper's §2.2 and Table 1.

    A spotlight beside camera 0 aimed at the plate centre with the paper's Table 1 values
    (I_a = −10, I_i = 80 grey levels of 8 bit, shininess 400) and k_r = 0.3, k_s = 0.5 (so
    that only the highlight saturates), 30 mm f/2
    lenses with 4.4 µm pixels focused at 600 mm (the 5 mm bulge is ~1.5 px out of focus), and
    2 % Gaussian noise.
    """
    fx = scene.cameras[0].fx
    pitch = 30.0 / fx  # the rig's lenses are 30 mm: pixel pitch that gives its fx
    light = Light(position=(-150.0, -200.0, 0.0), intensity=80 / 255, direction=(150.0, 200.0, 600.0),
                  cutoff=20.0, edge=5.0)
    return dataclasses.replace(
        scene,
        lighting=Lighting(ambient=-10 / 255, lights=(light,), diffuse=0.3, specular=0.5, shininess=400.0),
        optics=Optics(focal_length=30.0, f_number=2.0, focus_distance=600.0, pixel_pitch=pitch),
        noise=Noise(model="gaussian", sigma=2.0))
