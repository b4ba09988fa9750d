"""Where the preview frame's parts go and at what size the cameras are rendered: the frame's
layout (camera tiles, rig view, info area, control panel) and the scaled scenes of a drag."""
from __future__ import annotations

import dataclasses

from glsim.scene import Scene
from glsim.scene.camera import Camera


def frame_layout(size: tuple[int, int], cams) -> dict:
    """The boxes (x, y, w, h) of a ``size`` (W, H) frame: one tile per camera, each at its aspect,
    above the rig view and the info area; the control panel on the right."""
    W, H = size
    pw = min(300, max(200, W // 4))
    lw = W - pw
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
