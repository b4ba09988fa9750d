"""The preview's scene bookkeeping: which reference image a scene asks for (so that edits that
leave it unchanged keep the uploaded speckle), holding the speckle still on the specimen while
camera 1 moves, and writing the edited scene as TOML that :func:`glsim.scene.load_scene` reads
back."""
from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.io import images as io
from glsim.scene import Scene
from glsim.scene.load import _from_resolved
from glsim.stages.reference import _auto_camera, camera_scale


def reference_key(scene: Scene, nodes: np.ndarray, image_shape: tuple[int, int] | None = None) -> tuple:
    """Everything :func:`glsim.stages.reference.make_reference` makes the reference from, with
    the same arithmetic: two scenes with equal keys get the same reference image and camera.
    ``image_shape`` (H, W): the loaded reference image's, for a scene with ``speckle.image``."""
    sp, cam1 = scene.speckle, scene.cameras[0]
    if sp.image:
        cam = sp.camera or _auto_camera(nodes, cam1.center, sp.mm_per_px, (image_shape or (0, 0))[::-1])
        return ("image", str(scene.resolve(sp.image)), cam)
    c = camera_scale(cam1, nodes)
    m = sp.mm_per_px or c / sp.oversample
    cam = sp.camera or _auto_camera(nodes, cam1.center, m, None)
    dot = sp.dot_diameter_px * c / m
    edge = min(sp.edge_px * c / m, dot)
    return ("dots", cam, m, dot, edge, sp.density, sp.seed)


def same_reference(a: tuple | None, b: tuple | None) -> bool:
    """Whether two :func:`reference_key` results give the same reference. Dot and edge sizes
    may differ in the last bits (1e-12 relative): :func:`pin_speckle` cannot always hit the
    value exactly, and such a difference moves no dot edge by more than 1e-12 px."""
    if a is None or b is None or len(a) != len(b) or a[0] != b[0]:
        return False
    if a[0] == "image":
        return a == b
    return (a[1:3] == b[1:3] and a[5:] == b[5:]
            and all(math.isclose(x, y, rel_tol=1e-12, abs_tol=0.0) for x, y in zip(a[3:5], b[3:5])))


def _solve(target: float, c: float, m: float) -> float:
    """x with x·c/m == target in floating point (as make_reference evaluates it), or the
    nearest try."""
    x = target * m / c
    for _ in range(256):
        v = x * c / m
        if v == target:
            return x
        x = float(np.nextafter(x, math.inf if v < target else -math.inf))
    return target * m / c


def pin_speckle(scene: Scene, key: tuple, nodes: np.ndarray) -> Scene:
    """``scene`` with its [speckle] rewritten so that its reference equals the one of ``key``
    although camera 1 moved or zoomed: the speckle stays painted on the specimen (the same
    reference camera, scale and dots); its ``dot_diameter_px`` (camera-1 px) follows the new
    camera. Raises SceneError if the dots would become smaller than the generator allows."""
    sp = scene.speckle
    if key[0] == "image":
        return scene if sp.camera is not None else dataclasses.replace(
            scene, speckle=dataclasses.replace(sp, camera=key[2]))
    _, cam, m, dot, edge, _, _ = key
    c = camera_scale(scene.cameras[0], nodes)
    d = _solve(dot, c, m)
    e = d if edge == dot else _solve(edge, c, m)
    try:
        pinned = dataclasses.replace(sp, camera=cam, mm_per_px=m, dot_diameter_px=d, edge_px=min(e, d))
    except SceneError as exc:
        raise SceneError(exc.key, f"with camera 1 there the speckle dots would measure {d:.3g} px ({exc})",
                         "move camera 1 closer, lengthen its focal length, or enlarge the speckle first") from None
    return dataclasses.replace(scene, speckle=pinned)


FILE_KEYS = (("speckle", "image"), ("noise", "variance_file"))


def scene_toml(scene: Scene, directory: str | Path) -> str:
    """The resolved scene (every default filled, poses as R and t) as TOML text for a file in
    ``directory``: file paths are rewritten relative to it (absolute across drives)."""
    import tomli_w

    data, base = _from_resolved(scene.to_dict())
    directory = Path(directory).resolve()

    def rel(p: str) -> str:
        if not p:
            return p
        full = Path(base) / p if not Path(p).is_absolute() else Path(p)
        try:
            return Path(os.path.relpath(full, directory)).as_posix()
        except ValueError:
            return str(full)

    for table, name in FILE_KEYS:
        if isinstance(data.get(table), dict) and data[table].get(name):
            data[table][name] = rel(data[table][name])
    mesh = data.get("specimen", {}).get("mesh")
    if mesh:
        mesh["path"] = rel(mesh["path"])
        for k in ("files", "csv"):
            mesh[k] = [rel(p) for p in mesh.get(k, [])]
    head = "# written by glsim preview: the resolved scene (every default filled); load_scene reads it back\n"
    return head + tomli_w.dumps(data)


def save_scene(scene: Scene, path: str | Path) -> Path:
    """Write ``scene`` as TOML to ``path`` atomically; returns the path."""
    path = Path(path)
    if path.suffix.lower() != ".toml":
        raise SceneError(str(path), "a scene is saved as TOML", "give a file name ending in .toml")
    path.parent.mkdir(parents=True, exist_ok=True)
    return io.write_text(path, scene_toml(scene, path.parent))
