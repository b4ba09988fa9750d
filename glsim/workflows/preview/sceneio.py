"""The preview's scene bookkeeping: what the reference image is made from (so that edits that
leave it unchanged keep the uploaded speckle), holding the speckle still on the specimen while
camera 1 moves, and writing the edited scene as TOML that :func:`glsim.scene.load_scene` reads
back."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.io import images as io
from glsim.scene import Scene, Speckle
from glsim.scene.load import from_resolved


def reference_inputs(scene: Scene) -> tuple:
    """What the reference image is made from (glsim.imaging.reference.make_reference): the
    [speckle] and [specimen] tables, camera 1 (the generator sizes its dots in camera-1 pixels
    and faces the specimen's camera side) and the folder relative paths start in. Two scenes
    with equal inputs get the same reference."""
    return scene.speckle, scene.specimen, scene.cameras[0], scene.base_dir


def pinned_speckle(reference, folder: str | Path, name: str) -> Speckle:
    """A [speckle] table that gives back exactly ``reference`` (its float32 image, written as a
    float TIFF in ``folder``, and its camera): the speckle painted on the specimen stays as it is
    when camera 1 moves or zooms, as on a real specimen."""
    import tifffile

    path = Path(folder) / name
    if not path.is_file():
        with io.atomic_path(path) as tmp:
            tifffile.imwrite(tmp, np.ascontiguousarray(reference.image, np.float32), photometric="minisblack")
    return Speckle(image=str(path), camera=reference.camera)


FILE_KEYS = (("speckle", "image"), ("noise", "variance_file"), ("psf", "image"))


def scene_toml(scene: Scene, directory: str | Path) -> str:
    """The resolved scene (every default filled, poses as R and t) as TOML text for a file in
    ``directory``: file paths are rewritten relative to it (absolute across drives)."""
    import tomli_w

    data, base = from_resolved(scene.to_dict())
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


def save_scene(scene: Scene, path: str | Path, private: str | Path | None = None) -> Path:
    """Write ``scene`` as TOML to ``path`` atomically; returns the path. A reference image kept
    in the folder ``private`` (the preview's own, removed when it closes) is copied beside the
    TOML as ``<name>_speckle.tif`` first."""
    import dataclasses
    import shutil

    path = Path(path)
    if path.suffix.lower() != ".toml":
        raise SceneError(str(path), "a scene is saved as TOML", "give a file name ending in .toml")
    path.parent.mkdir(parents=True, exist_ok=True)
    image = scene.speckle.image
    if image and private is not None and Path(image).parent == Path(private):
        dest = path.with_name(path.stem + "_speckle.tif")
        with io.atomic_path(dest) as tmp:
            shutil.copyfile(image, tmp)
        scene = dataclasses.replace(scene, speckle=dataclasses.replace(scene.speckle, image=str(dest.resolve())))
    return io.write_text(path, scene_toml(scene, path.parent))
