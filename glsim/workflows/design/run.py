"""Running a design: one row per (set-up, speckle seed, DIC setting[, noise seed]), each cached.

Quick rows (per set-up, speckle seed and DIC setting) hold the Cramér–Rao noise map on a subset
grid (:mod:`~glsim.workflows.design.quick`). Engine rows (per noise seed as well) render a noisy
image set — the reference state (step 0), the deformed ``step`` and the reference state again with
another noise field (the static pair of the noise floor) — measure it with the engine and keep the
displacements with the exact truth at the engine's subset centres (the material point seen at the
centre, moved by the FE field of ``step`` and projected into the camera: px, and mm through the
camera scale Z/√(fx·fy) at the centre). A setting with a strain window also keeps the engine's strain
at its strain points with the exact strain there (:mod:`~glsim.workflows.design.strain`). With a ``[resolution]`` table, resolution rows (per set-up,
speckle seed and setting, under the first noise seed) measure the sinusoid sweep on a flat plate
(:mod:`~glsim.workflows.design.resolution`).

Stereo designs (engine pyvale3d) have stereo engine rows instead (:mod:`~glsim.workflows.design.stereo`):
both cameras rendered, the rig handed to the engine chosen by :func:`rig_cameras`; their quick rows
stay 2-D, on camera 0; their resolution rows measure an out-of-plane sinusoid (and, with a strain
window, an in-plane one) with the stereo engine (:func:`~glsim.workflows.design.resolution.stereo_sweep_row`).

A row lives in ``DIR/rows/<key>/`` (``result.npz``, then ``row.json`` last); ``<key>`` hashes its
inputs (the resolved scene, camera(s), step, ROI margin, setting, seeds, engine, for stereo the
calibration handed to the engine, this format's version), so a run resumes where it stopped and a
changed spec recomputes only the changed rows.
"""
from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from glsim.io import images as io
from glsim.scene import Scene
from glsim.io.calibfiles import pyvale_calibration
from glsim.io.hashes import sha256_file
from glsim.io.npzfile import NpzError, read_npz
from glsim.limits import parse_nested, read_bounded
from glsim.workflows.design.calibration import calibrated_rig, inputs_hash
from glsim.scene.camera import Camera
from glsim.workflows.design import resolution, stereo
from glsim.workflows.design.engine import Engine
from glsim.workflows.design.planar import engine_row, prepare, quick_row, setup_scene
from glsim.workflows.design.spec import Design, DicSetting, row_key

FORMAT = "glsim-design/1"
ROW_VERSION = 2   # 2: row.json vouches for result.npz (size, SHA-256, array names)
RESOLUTION = ":resolution"   # suffix of the sinusoid sweep's rows' kind (per set-up, speckle seed, setting)
@dataclass(frozen=True)
class Row:
    key: str
    kind: str                 # "quick" or the engine's name
    setup: str                # variant id
    speckle_seed: int | None
    setting: DicSetting
    noise_seed: int | None

    def meta(self) -> dict:
        return {"key": self.key, "kind": self.kind, "setup": self.setup, "speckle_seed": self.speckle_seed,
                "setting": self.setting.name, "subset_size": self.setting.subset_size,
                "subset_step": self.setting.subset_step, "shape_function": self.setting.shape_function,
                "noise_seed": self.noise_seed}


def rig_cameras(design: Design, scene: Scene, out: Path | None = None) -> tuple[Camera, Camera]:
    """The stereo rig handed to the engine as its calibration: two glsim cameras, camera 0 first.
    ``[calibration] rig = "exact"``: the scene's own cameras, no calibration error; ``"targets"``:
    the cameras calibrated from a simulated target library of the set-up's rig, made (or read back)
    in ``out/calibration``."""
    if design.rig == "exact":
        return scene.camera(design.cameras[0]), scene.camera(design.cameras[1])
    rig = calibrated_rig(design.calibration, _stereo_first(design, scene), Path(out) / "calibration")
    return rig.cam0, rig.cam1


def calibration_report(design: Design, scene: Scene, out: Path) -> dict:
    """The set-up's calibration errors against the truth (zeros for the exact rig)."""
    return calibrated_rig(design.calibration, _stereo_first(design, scene), Path(out) / "calibration").report


def _stereo_first(design: Design, scene: Scene) -> Scene:
    """The scene with the design's stereo pair as its first two cameras (what the calibration takes)."""
    return dataclasses.replace(scene, cameras=(scene.camera(design.cameras[0]), scene.camera(design.cameras[1])))


def calibration_identity(design: Design, scene: Scene) -> dict:
    """What a stereo row's cache key holds of the rig: its kind and the calibration the engine
    gets — for a calibrated rig the calibration's inputs (cameras, spec, noise, seed), which
    determine its result, so the key is known before the calibration runs."""
    if design.rig == "exact":
        return {"rig": design.rig, "pyvale": pyvale_calibration(*rig_cameras(design, scene))}
    return {"rig": design.rig, "inputs": inputs_hash(design.calibration, _stereo_first(design, scene))}


def rows(design: Design, engine_name: str | None) -> list[Row]:
    """Every row of the design in a fixed order (set-up, speckle seed, setting, kind, noise seed)."""
    out = []
    for v in design.plan.variants:
        for ss in design.speckle_seeds:
            scene = setup_scene(v.scene, ss)
            base = {"format": FORMAT, "version": ROW_VERSION, "scene": json.loads(scene.to_json()),
                    "camera": design.camera, "step": design.step, "roi_margin": design.roi_margin}
            if design.stereo:   # 2-D designs keep their keys (and caches)
                base.update(cameras=list(design.cameras), calibration=calibration_identity(design, scene))
            for s in design.settings:
                kinds = [("quick", None)] + ([(engine_name, n) for n in design.noise_seeds] if engine_name else [])
                if engine_name and design.resolution is not None:
                    kinds.append((engine_name + RESOLUTION, design.noise_seeds[0]))
                for kind, n in kinds:
                    extra = {"resolution": [list(design.resolution.periods_px), design.resolution.amplitude_px]} \
                        if kind.endswith(RESOLUTION) else {}
                    if extra and (design.stereo or s.strain is not None):   # 2-D sweeps without strain keep their keys
                        extra["sweep"] = "stereo-normal" if design.stereo else "strain"
                    key = row_key({**base, "setting": s.name, "kind": kind, "noise_seed": n, **extra})
                    out.append(Row(key, kind, v.id, ss, s, n))
    return out


ROW_META_BYTES = 1 << 20    # row.json: a row's meta (its key, setting, seeds, the result's hash)


def load_row(folder: Path, key: str) -> dict | None:
    """A finished row's arrays (with its meta), or None — computed again — when it is missing, not
    this key's, or its result.npz is not the one row.json vouches for (size and SHA-256, checked
    before the arrays are read, each bounded by its header: :func:`glsim.io.npzfile.read_npz`)."""
    try:
        meta = parse_nested(json.loads, read_bounded(folder / "row.json", ROW_META_BYTES).decode("utf-8"),
                            "row.json")
        result = folder / "result.npz"
        if not (isinstance(meta, dict) and meta.get("key") == key and isinstance(meta.get("arrays"), list)
                and result.is_file() and not result.is_symlink() and result.stat().st_size == meta.get("bytes")
                and sha256_file(result) == meta.get("sha256")):
            return None
        return {"meta": meta, **read_npz(result, [str(a) for a in meta["arrays"]])}
    except (OSError, ValueError, UnicodeDecodeError, NpzError):
        return None


def save_row(folder: Path, meta: dict, arrays: dict) -> dict:
    """result.npz, then row.json last with its size, SHA-256 and array names (what load_row checks)."""
    folder.mkdir(parents=True, exist_ok=True)
    with io.atomic_path(folder / "result.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    result = folder / "result.npz"
    meta = {**meta, "arrays": sorted(arrays), "bytes": result.stat().st_size, "sha256": sha256_file(result)}
    io.write_text(folder / "row.json", json.dumps(meta, indent=2))
    return meta


def run(design: Design, out: Path, eng: Engine | None, progress=None) -> list[dict]:
    """Compute (or reuse) every row; returns their results in :func:`rows` order."""
    todo = rows(design, eng.name if eng else None)
    variants = {v.id: v for v in design.plan.variants}
    prepared: dict = {}
    results, t0, fresh = [], time.perf_counter(), 0
    for i, row in enumerate(todo):
        folder = out / "rows" / row.key
        res = load_row(folder, row.key)
        if res is None:
            pk = (row.setup, row.speckle_seed)
            if pk not in prepared:
                prepared.clear()   # one set-up at a time: rows are ordered by set-up
                scene = setup_scene(variants[row.setup].scene, row.speckle_seed)
                prepared[pk] = stereo.prepare(scene, design.cameras, design.step, design.roi_margin) \
                    if design.stereo else prepare(scene, design.camera, design.step, design.roi_margin)
            t1 = time.perf_counter()
            p = prepared[pk].base if design.stereo else prepared[pk]
            if row.kind == "quick":
                arrays = quick_row(p, row.setting)
            elif row.kind.endswith(RESOLUTION) and design.stereo:
                arrays = resolution.stereo_sweep_row(p.scene, design.cameras, p.mesh, row.setting, row.noise_seed,
                                                     design.resolution.periods_px, design.resolution.amplitude_px,
                                                     eng, folder, design.roi_margin, rig_cameras(design, p.scene, out))
            elif row.kind.endswith(RESOLUTION):
                arrays = resolution.sweep_row(p.scene, p.camera, p.mesh, row.setting, row.noise_seed,
                                              design.resolution.periods_px, design.resolution.amplitude_px,
                                              eng, folder, design.roi_margin)
            elif design.stereo:
                arrays = stereo.engine_row(prepared[pk], row.setting, row.noise_seed, eng, folder,
                                           rig_cameras(design, p.scene, out))
            else:
                arrays = engine_row(p, row.setting, row.noise_seed, eng, folder)
            meta = save_row(folder, {**row.meta(), "seconds": time.perf_counter() - t1}, arrays)
            res, fresh = {"meta": meta, **arrays}, fresh + 1
        results.append(res)
        if progress:
            progress(i + 1, len(todo), row, fresh, time.perf_counter() - t0)
    return results


def print_progress(done: int, total: int, row: Row, fresh: int, seconds: float) -> None:
    eta = seconds / fresh * (total - done) if fresh else 0.0
    seeds = f", noise seed {row.noise_seed}" if row.noise_seed is not None else ""
    sys.stderr.write(f"[{done}/{total}] {row.setup} {row.setting.name} {row.kind}{seeds}"
                     f"  ({seconds:.0f} s, ETA {eta:.0f} s)\n")
    sys.stderr.flush()
