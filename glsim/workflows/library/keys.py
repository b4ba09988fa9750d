"""What a library's variants share, by content: the keys of their meshes, their reference images
and their truth files (variants whose truth key is equal share one ``truth/{key}.truth``)."""
from __future__ import annotations

import hashlib
import json

import numpy as np

from glsim.scene import Scene


def mesh_key(scene: Scene) -> str:
    """What the specimen mesh depends on (variants with the same key share one mesh)."""
    d = scene.to_dict()
    return json.dumps({"specimen": d["specimen"], "base_dir": d["base_dir"]}, sort_keys=True)


TRUTH_DIR = "truth"      # a library's truth files: truth/{key}.truth, one per distinct truth key
KEY_VERSION = 1          # of what truth_keys hashes: bump it when that changes
PATTERN_KEYS = ("seed", "density", "dot_diameter_px", "edge_px")   # speckle keys that only draw the pattern


def _digest(arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def truth_keys(scene: Scene, mesh, cameras, steps, dtype: str, cache: dict | None = None) -> dict:
    """(camera name, step) → the truth key of that image: SHA-256 (first 32 hex digits) of
    everything that changes a bit of its compact truth file — the mesh (placed nodes, quads,
    labels, every step's displacements: the geometry file its header names), the step, the
    camera (intrinsics, distortion, pose, size, as the header holds it), camera 0, the specimen
    table and the speckle's placement (what the reference camera depends on: not its seed,
    density or dot size), render mode, precision, backend, samples per pixel, a quadratic
    mesh's pieces per element side, the truth dtype, and the truth format's and this key's
    versions; with a rolling shutter its line time and the exposure's motion (each row's state).
    Noise, lighting, optics, the speckle pattern and the output format do not enter: variants
    differing only in those share one truth file. ``cache``: mesh digests by :func:`mesh_key`,
    kept between calls."""
    from glsim.io import truthcodec

    cache = {} if cache is None else cache
    mkey = mesh_key(scene)          # what the mesh depends on: one mesh, one digest
    if mkey not in cache:
        cache[mkey] = _digest([mesh.nodes, mesh.quads, mesh.element_labels, *mesh.displacements,
                               *([] if mesh.patches is None else [mesh.patches])])
    d = scene.to_dict()
    sp = {k: v for k, v in d["speckle"].items() if k not in PATTERN_KEYS}
    sp["image"] = str(scene.resolve(sp["image"])) if sp["image"] else ""
    r = scene.render
    base = {"version": [truthcodec.FORMAT, truthcodec.VERSION, KEY_VERSION], "dtype": dtype, "mesh": cache[mkey],
            "specimen": d["specimen"], "specimen_dir": d["base_dir"], "speckle": sp,
            "camera0": truthcodec.camera_dict(scene.cameras[0]),
            "render": [r.mode, r.precision, r.backend, r.samples_per_pixel, r.subsamples]
            + ([r.pieces] if mesh.patches is not None else [])}
    if scene.sensor is not None and scene.sensor.line_time > 0:   # (other keys unchanged)
        base["rolling"] = {"line_time": scene.sensor.line_time,
                           **{k: d["exposure"].get(k) for k in ("velocity", "angular_velocity", "centre")}}
    return {(c, s): hashlib.sha256(json.dumps({**base, "step": s, "camera": truthcodec.camera_dict(scene.camera(c))},
                                              sort_keys=True).encode()).hexdigest()[:32]
            for s in steps for c in cameras}


def reference_key(scene: Scene, backend: str) -> str:
    """What a Renderer's mesh, reference image and backend depend on (a quadratic mesh's pieces
    too): variants with the same key are rendered by one Renderer (one GL context, textures and
    programs)."""
    d = scene.to_dict()
    return json.dumps({"specimen": d["specimen"], "speckle": d["speckle"], "camera0": d["cameras"][0],
                       "base_dir": d["base_dir"], "backend": backend, "pieces": scene.render.pieces}, sort_keys=True)
