"""Scene files: TOML (or a written ``scene.json``) → the frozen :class:`Scene`.

A scene file has the same structure as these dataclasses (see ``examples/*.toml``)::

    seed = 0
    [[cameras]]                 # one table per camera; the first is the world frame by default
    name = "cam0"               # default cam0, cam1, … by position
    size = [1624, 1234]         # W, H px
    fx = 6818.0                 # fx, fy, cx, cy, skew px (skew default 0)
    bit_depth = 8               # 8, 10, 12 or 16
    distortion = {k1 = -0.05}   # OpenCV coefficients k1 k2 p1 p2 k3 k4 k5 k6 s1 s2 s3 s4
    pose = {rvec = [0, 0, 0], t = [0, 0, 0]}      # world→camera, or R = 3×3 instead of rvec,
    # or pose = {look_at = {eye = [...], target = [...], up = [...]}}, or for a later camera
    # pose = {stereo = {Tx, Ty, Tz, Theta, Phi, Psi}}: relative to the first camera (Stereo).
    [specimen]                  # exactly one of [specimen.mesh], [specimen.plate], [specimen.bulge]
    pose = {rvec = [...], t = [...]}              # specimen→world: X_world = R·X + t
    [speckle]  [render]  [output]                 # all keys optional

Every key is checked: unknown keys, wrong types, missing keys, impossible values and missing
files raise :class:`SceneError` naming the key (``cameras[1].pose.stereo.Psi``) and the fix.
Units: millimetres, pixels, degrees for the stereo angles, radians for ``rvec``.
"""
from __future__ import annotations

import json
import typing
from pathlib import Path

from glsim.errors import SceneError
from glsim.limits import check_nesting, not_a_file, parse_nested
from glsim.scene.camera import Camera
from glsim.scene.model import Scene
from glsim.scene.tables import SECTIONS, build, coerce, reject_unknown

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib


def scene_from_dict(data: dict, base_dir: str | Path = ".") -> Scene:
    """Build a Scene from parsed TOML (see the module docstring for the layout)."""
    check_nesting(data, "scene")
    reject_unknown(data, SECTIONS, "")
    tables = data.get("cameras")
    if not isinstance(tables, list) or not tables:
        raise SceneError("cameras", "at least one [[cameras]] table is required",
                         "add [[cameras]] with size, fx, fy, cx, cy")
    cameras: list[Camera] = []
    for i, table in enumerate(tables):
        first = cameras[0] if cameras else None
        cameras.append(build(Camera, table, f"cameras[{i}]", first, name=f"cam{i}"))
    hints = typing.get_type_hints(Scene)
    rest = {k: coerce(data[k], hints[k], k) for k in SECTIONS[1:] if k in data}
    return Scene(cameras=tuple(cameras), base_dir=str(Path(base_dir).resolve()), **rest)


def from_resolved(data: dict) -> tuple[dict, str]:
    """The layout of :meth:`Scene.to_dict` (a written ``scene.json``) as the scene-file layout:
    no nulls, poses as ``pose = {R, t}``, and the recorded base directory."""
    def drop_none(x):
        if isinstance(x, dict):
            return {k: drop_none(v) for k, v in x.items() if v is not None}
        return [drop_none(v) for v in x] if isinstance(x, list) else x

    d = drop_none(data)
    base = d.pop("base_dir", ".")
    if not isinstance(base, str):
        raise SceneError("base_dir", f"expected a directory name, got {base!r}", "give the scene's directory")
    posed = list(d.get("cameras", [])) + [d.get("specimen", {}), d.get("speckle", {}).get("camera", {})]
    for table in posed:
        if isinstance(table, dict) and "R" in table:
            table["pose"] = {"R": table.pop("R"), "t": table.pop("t")}
    return d, base


def load_scene(path: str | Path) -> Scene:
    """Read and validate a TOML scene file (relative paths in it start at its directory), or a
    ``scene.json`` that glsim wrote next to its outputs (the resolved scene, re-rendered as is)."""
    path = Path(path)
    why = not_a_file(path)
    if why:
        raise SceneError(str(path), "scene file not found" if why == "not found" else why, "check the path")
    if path.suffix == ".json":
        try:
            data, base = from_resolved(parse_nested(json.loads, path.read_text(encoding="utf-8"), str(path)))
        except SceneError:
            raise
        except (ValueError, AttributeError, KeyError, TypeError) as exc:
            raise SceneError(str(path), f"is not a scene.json written by glsim ({exc})",
                             "give a TOML scene file or an unmodified scene.json") from None
        return scene_from_dict(data, base)
    try:
        data = parse_nested(tomllib.loads, path.read_text(encoding="utf-8"), str(path))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError(str(path), f"is not a valid TOML file ({exc})", "fix the syntax there") from None
    return scene_from_dict(data, path.parent)
