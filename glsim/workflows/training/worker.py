"""The worker side of a training set: render one shard's samples and write the shard.

A task is plain data (the shard's name, its samples' resolved scenes, the [training] table), so
it runs the same in this process, a local process pool or on a Dask worker
(:func:`glsim.workflows.library.runner.execute`). Each sample is its cameras rendered at step 0
and at the training step with truth, and the labels between them
(:func:`glsim.workflows.training.labels.pair_labels`). The shard is written under a temporary
name inside the output directory and renamed when complete.

Renderer reuse: a fresh Renderer on the worker thread's GL context costs mostly its reference
image (the speckle drawn onto the undeformed specimen, prefiltered and uploaded). Consecutive
samples whose speckle, camera 0 and undeformed geometry are equal — a displacement field varied
under one speckle — keep the renderer and only swap its mesh (:meth:`glsim.render.Renderer.load_displacements`).
"""
from __future__ import annotations

import hashlib
import json
import os
import threading
import time
from pathlib import Path

import numpy as np

from glsim.io import atomic
from glsim.workflows.training import shards as sh
from glsim.workflows.training.spec import crop_offset

_LOCAL = threading.local()


def _reference_key(scene, mesh) -> str:
    """What the reference image depends on: the speckle, camera 0, the specimen's placement and
    its undeformed geometry (not its displacements)."""
    d = scene.to_dict()
    h = hashlib.sha256()
    for a in (mesh.nodes, mesh.quads, mesh.element_labels):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return json.dumps({"speckle": d["speckle"], "camera0": d["cameras"][0], "base_dir": d["base_dir"],
                       "pose": [scene.specimen.R, scene.specimen.t], "geometry": h.hexdigest(),
                       "pieces": scene.render.pieces, "backend": scene.render.backend}, sort_keys=True, default=str)


def renderer_for(scene):
    """This thread's Renderer for ``scene`` (on its GL context): the last sample's, with its mesh
    swapped (:meth:`Renderer.load_displacements`), when their reference key (:func:`_reference_key`) is the same;
    else a new one (the old one's GL resources released)."""
    from glsim.io.fe import specimen_mesh
    from glsim.render import Renderer
    from glsim.workflows.library import worker as lw

    mesh = specimen_mesh(scene)
    backend = scene.render.backend
    key = "training:" + _reference_key(scene, mesh)
    if mesh.is_quadratic or scene.exposure is not None:   # (their renderers cache more per mesh: none kept)
        _LOCAL.count = getattr(_LOCAL, "count", 0) + 1
        key += f":{_LOCAL.count}"
    r = lw.thread_renderer(key, lambda: Renderer(scene, backend, ctx=lw.thread_context() if backend == "gl" else None,
                                                 mesh=mesh))
    if r.mesh is not mesh:
        r.load_displacements(scene, mesh)
    return r


def _scene(scene_json: str):
    from glsim.workflows.library.worker import _scene as library_scene
    return library_scene(scene_json)


def _image(res, dtype: str | None) -> np.ndarray:
    img = res.image
    want = dtype or ("uint8" if res.camera.bit_depth == 8 else "uint16")
    return img if img.dtype == np.dtype(want) else img.astype(want)


def sample_members(task: dict, sample: dict) -> dict[str, bytes]:
    """One sample's members (name → bytes): its images at step 0 and at the step, the labels kept
    (cropped with the images), the JSON of its values."""
    from glsim.workflows.training.labels import pair_labels

    t = task["training"]
    scene = _scene(sample["scene"])
    r = renderer_for(scene)
    step, key = t["step"], sample["variant"]
    ref, dfm, images = {}, {}, {}
    jobs = [{"camera": c, "step": s, "truth": True, "quantize": True} for c in task["cameras"] for s in (0, step)]
    for job, res in zip(jobs, r.render_many(jobs)):
        (ref if job["step"] == 0 else dfm)[job["camera"]] = res.truth
        images[job["camera"], job["step"]] = _image(res, t["image_dtype"])
    labels = pair_labels(scene, step, ref, dfm, mesh=r.mesh)
    keep = task["labels"] or sorted(labels)
    missing = [k for k in keep if k not in labels]
    if missing:
        raise ValueError(f"pair_labels gave no {missing} for variant {key} (it gave {sorted(labels)})")
    cams = [scene.camera(c) for c in task["cameras"]]
    crop = t["crop"]                # (the same offset in every camera, within the smallest)
    x0, y0 = crop_offset(task["seed"], sample["index"], (min(c.width for c in cams), min(c.height for c in cams)),
                         crop)
    cut = (lambda a: a) if crop is None else (lambda a: a[y0:y0 + crop[1], x0:x0 + crop[0]])
    members = {}
    for c, i in zip(task["cameras"], task["indices"]):
        for s, tag in ((0, "ref"), (step, "def")):
            ext, data = sh.image_member(np.ascontiguousarray(cut(images[c, s])), t["image_format"])
            members[f"{key}.cam{i}_{tag}.{ext}"] = data
    for k in keep:
        a = labels[k]               # (H, W[, k]) maps of a camera's pixels
        members[f"{key}.{k}.npy"] = sh.npy_bytes(cut(a) if a.ndim >= 2 else a)
    seeds = {"speckle.seed": scene.speckle.seed}
    field = getattr(scene.specimen, "field", None)
    if field is not None and getattr(field, "seed", None) is not None:
        seeds["specimen.field.seed"] = field.seed
    if scene.noise is not None or scene.sensor is not None:     # (the scene's seed draws the noise)
        seeds["seed"] = scene.seed
    members[f"{key}.json"] = sh.json_bytes({
        "variant": key, "index": sample["index"], "params": sample["params"], "seeds": seeds, "step": step,
        "cameras": {f"cam{i}": c for c, i in zip(task["cameras"], task["indices"])},
        "crop": None if crop is None else [x0, y0, crop[0], crop[1]],
        "labels": sorted(keep)})
    return members


def shard_task(task: dict) -> list[dict]:
    """Render the samples of ``task`` and write its shard (temporary, then renamed inside the
    output directory); returns its manifest record."""
    t0 = time.perf_counter()
    members: dict[str, bytes] = {}
    for sample in task["samples"]:
        members.update(sample_members(task, sample))
    path = Path(task["out"]) / task["shard"]
    h = hashlib.sha256()
    try:
        with atomic.atomic_path(path) as tmp:
            with atomic.open_temporary(tmp) as f:
                sh.write_tar(_Hashing(f, h), members)
            size = os.path.getsize(tmp)
    except OSError as exc:
        from glsim.workflows.library.worker import WriteError
        raise WriteError(f"{path}: cannot be written ({exc.strerror or exc})"
                         + (" — the disk is full: free space, then run the same command again to resume"
                            if exc.errno == 28 else " — check that the directory is writable, then run the same "
                            "command again to resume")) from None
    return [{"shard": task["shard"], "samples": len(task["samples"]), "bytes": size, "sha256": h.hexdigest(),
             "seconds": time.perf_counter() - t0}]


class _Hashing:
    """A binary file that hashes what is written to it (the shard's SHA-256 without reading it back)."""

    def __init__(self, f, h):
        self.f, self.h = f, h

    def write(self, b) -> int:
        self.h.update(b)
        return self.f.write(b)

    def tell(self) -> int:
        return self.f.tell()


def make_task(plan, shard, out: Path) -> dict:
    """The plain-data task of one shard."""
    t = plan.training
    return {"shard": shard.name, "out": str(out), "training": t.as_dict(), "cameras": list(plan.cameras),
            "indices": list(plan.indices), "labels": list(plan.labels), "seed": plan.library.seed,
            "samples": [{"variant": v.id, "index": v.index, "params": v.params, "scene": v.scene.to_json()}
                        for v in (plan.library.variant(vid) for vid in shard.variants)]}
