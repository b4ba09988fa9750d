"""Cameras as plain JSON data and back: one codec for every file that records a camera (the
truth files' headers, a calibration library's library.json)."""
from __future__ import annotations

import dataclasses

from glsim.scene.camera import Camera, Distortion


def camera_to_dict(cam: Camera) -> dict:
    """Every field of ``cam`` as JSON-ready data: lists for size, R and t, the distortion as a
    dict of its coefficients."""
    d = dataclasses.asdict(cam)
    d["size"] = list(cam.size)
    d["R"] = [list(r) for r in cam.R]
    d["t"] = list(cam.t)
    return d


def camera_from_dict(d: dict) -> Camera:
    """The camera of a :func:`camera_to_dict` dict (or its JSON read back; no "distortion" entry:
    none). A dict that is not one raises TypeError, KeyError or ValueError (SceneError for a
    value the camera refuses)."""
    d = dict(d)
    d["distortion"] = Distortion(**d.get("distortion", {}))
    d["size"] = tuple(d["size"])
    d["R"] = tuple(tuple(r) for r in d["R"])
    d["t"] = tuple(d["t"])
    return Camera(**d)
