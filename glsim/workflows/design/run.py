"""Running a design: one row per (set-up, speckle seed, DIC setting[, noise seed]), each cached.

Quick rows (per set-up, speckle seed and DIC setting) hold the Cramér–Rao noise map on a subset
grid (:mod:`~glsim.workflows.design.quick`). Engine rows (per noise seed as well) render a noisy
image set — the reference state (step 0), the deformed ``step`` and the reference state again with
another noise field (the static pair of the noise floor) — measure it with the engine and keep the
displacements with the exact truth at the engine's subset centres (the material point seen at the
centre, moved by the FE field of ``step`` and projected into the camera: px, and mm through the
camera scale Z/√(fx·fy) at the centre). With a ``[resolution]`` table, resolution rows (per set-up,
speckle seed and setting, under the first noise seed) measure the sinusoid sweep on a flat plate
(:mod:`~glsim.workflows.design.resolution`).

Stereo designs (engine pyvale3d) have stereo engine rows instead (:mod:`~glsim.workflows.design.stereo`):
both cameras rendered, the rig handed to the engine chosen by :func:`rig_cameras`; their quick and
resolution rows stay 2-D, on camera 0.

A row lives in ``DIR/rows/<key>/`` (``result.npz``, then ``row.json`` last); ``<key>`` hashes its
inputs (the resolved scene, camera(s), step, ROI margin, setting, seeds, engine, for stereo the
calibration handed to the engine, this format's version), so a run resumes where it stopped and a
changed spec recomputes only the changed rows.
"""
from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from glsim.effects import noise as noisemod
from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io.fe import specimen_mesh
from glsim.io.truth import mesh_geometry
from glsim.scene.locate import points_truth
from glsim.render import Renderer
from glsim.scene import Scene
from glsim.io.calibfiles import pyvale_calibration
from glsim.scene.camera import Camera, project_camera_frame
from glsim.workflows.design import quick, resolution
from glsim.workflows.design.engine import Engine, write_exchange
from glsim.workflows.design.spec import Design, DicSetting, row_key

FORMAT = "glsim-design/1"
ROW_VERSION = 1
RESOLUTION = ":resolution"   # suffix of the sinusoid sweep's rows' kind (per set-up, speckle seed, setting)
STATIC_STREAM = 0x5EED   # the static pair's second noise field: seed derived from the realisation's


@dataclass(frozen=True)
class Prepared:
    """A set-up with one speckle pattern, ready to measure: its noise-free reference image
    (full scale, float64), per-pixel variance, ROI and what renders and the truth need."""
    scene: Scene
    camera: str
    step: int
    mesh: object
    reference: object
    image: np.ndarray
    variance: np.ndarray
    roi: np.ndarray


def setup_scene(scene: Scene, speckle_seed: int | None) -> Scene:
    return scene if speckle_seed is None else scene.replace(speckle={"seed": int(speckle_seed)})


def static_seed(noise_seed: int) -> int:
    """The second noise seed of a static pair, distinct from any small seed a spec lists."""
    return int(np.random.SeedSequence([noise_seed, STATIC_STREAM]).generate_state(1)[0])


def prepare(scene: Scene, camera: str, step: int, margin: int) -> Prepared:
    """Render the noise-free reference image and the truth masks; ROI = specimen pixels at step 0
    and at ``step``, eroded by ``margin`` px."""
    mesh = specimen_mesh(scene)
    with Renderer(scene.replace(noise=None), mesh=mesh) as r:
        r0 = r.render(camera, 0, truth=True)
        rk = r.render(camera, step, truth=True)
        reference = r.reference
    roi = r0.truth.mask & rk.truth.mask
    if margin:
        roi = ndimage.binary_erosion(roi, iterations=margin)
    if not roi.any():
        raise GlsimError(f"camera {camera}: no pixel sees the specimen at steps 0 and {step} (ROI margin {margin} px)"
                         " — point the camera at the specimen or lower roi_margin")
    cam = scene.camera(camera)
    table = None
    if scene.noise is not None and scene.noise.model == "heteroscedastic":
        table = noisemod.load_variance_table(scene.resolve(scene.noise.variance_file), cam.bit_depth)
    image = np.asarray(r0.image, np.float64)
    return Prepared(scene, camera, step, mesh, reference, image,
                    quick.pixel_variance(image, scene.noise, cam.bit_depth, table), roi)


def truth_px(prep: Prepared, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """Exact truth at subset centres: u, v (px), mm per px there, valid."""
    cam = prep.scene.camera(prep.camera)
    uv = np.stack([x, y], axis=1).astype(np.float64)
    t = points_truth(mesh_geometry(prep.mesh), cam, uv, prep.step)
    moved, ok = project_camera_frame(np.nan_to_num(t.X_deformed), cam)
    d = moved - uv
    valid = t.valid & ok
    scale = t.X_undeformed[:, 2] / math.sqrt(cam.fx * cam.fy)
    return {"truth_u": np.where(valid, d[:, 0], np.nan), "truth_v": np.where(valid, d[:, 1], np.nan),
            "scale": np.where(valid, scale, np.nan), "truth_valid": valid}


def quick_at(prep: Prepared, setting: DicSetting, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """The Cramér–Rao σ at centres (x, y) rounded to pixels; ∞ where the subset leaves the image."""
    c = np.stack([np.rint(x), np.rint(y)], axis=1).astype(np.int64)
    H, W = prep.image.shape
    h = setting.subset_size // 2
    inside = (c[:, 0] >= h + 1) & (c[:, 0] < W - h - 1) & (c[:, 1] >= h + 1) & (c[:, 1] < H - h - 1)
    out = {k: np.full(len(c), np.inf if k.startswith("sigma") else np.nan) for k in ("sigma_u", "sigma_v", "sssig_x", "sssig_y")}
    if inside.any():
        res = quick.crb(prep.image, prep.variance, c[inside], setting.subset_size, setting.shape_function)
        for k in out:
            out[k][inside] = res[k]
    return {f"quick_{k}": v for k, v in out.items()}


def quick_row(prep: Prepared, setting: DicSetting) -> dict[str, np.ndarray]:
    centres = quick.grid_centres(prep.roi, setting.subset_size, setting.subset_step)
    x, y = centres[:, 0].astype(np.float64), centres[:, 1].astype(np.float64)
    return {"x": x, "y": y, **quick_at(prep, setting, x, y), **truth_px(prep, x, y)}


def noisy_images(prep: Prepared, noise_seed: int) -> list[np.ndarray]:
    """[reference, static, deformed] as the camera writes them (quantised), in full scale."""
    cam = prep.scene.camera(prep.camera)
    full = float(2 ** cam.bit_depth - 1)
    images = []
    for seed, step in ((noise_seed, 0), (static_seed(noise_seed), 0), (noise_seed, prep.step)):
        with Renderer(prep.scene.replace(seed=seed), mesh=prep.mesh, reference=prep.reference) as r:
            images.append(np.asarray(r.render(prep.camera, step, quantize=True).image, np.float64) / full)
    return images


def engine_row(prep: Prepared, setting: DicSetting, noise_seed: int, eng: Engine, folder: Path) -> dict:
    ref, static, deformed = noisy_images(prep, noise_seed)
    # how far the initial FFT search looks: the truth's largest shift over the ROI's corners and centre
    ys, xs = np.nonzero(prep.roi)
    probe = truth_px(prep, xs[:: max(1, len(xs) // 200)].astype(float), ys[:: max(1, len(ys) // 200)].astype(float))
    reach = np.nanmax(np.abs(np.concatenate([probe["truth_u"], probe["truth_v"]])), initial=0.0)
    write_exchange(folder / "exchange", ref, [static, deformed], prep.roi, setting.subset_size,
                   setting.subset_step, setting.shape_function, max(16, int(math.ceil(1.5 * reach)) + 4))
    m = eng.measure(folder / "exchange")
    return {"x": m.x, "y": m.y, "static_u": m.u[0], "static_v": m.v[0], "static_valid": m.valid[0],
            "u": m.u[1], "v": m.v[1], "valid": m.valid[1], "cost": m.cost[1], "engine_seconds": np.float64(m.seconds),
            "engine_version": np.str_(m.version), **quick_at(prep, setting, m.x, m.y), **truth_px(prep, m.x, m.y)}


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


def rig_cameras(design: Design, scene: Scene) -> tuple[Camera, Camera]:
    """The stereo rig handed to the engine as its calibration: two glsim cameras, camera 0 first.
    ``[calibration] rig = "exact"``: the scene's own cameras, no calibration error."""
    if design.rig == "exact":
        return scene.camera(design.cameras[0]), scene.camera(design.cameras[1])
    raise GlsimError(f"calibration.rig: {design.rig!r} is not supported — write rig = \"exact\"")


def calibration_identity(design: Design, scene: Scene) -> dict:
    """What a stereo row's cache key holds of the rig: its kind and the calibration the engine gets."""
    return {"rig": design.rig, "pyvale": pyvale_calibration(*rig_cameras(design, scene))}


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
                    key = row_key({**base, "setting": s.name, "kind": kind, "noise_seed": n, **extra})
                    out.append(Row(key, kind, v.id, ss, s, n))
    return out


def load_row(folder: Path, key: str) -> dict | None:
    """A finished row's arrays (with its meta), or None when it is missing or not this key's."""
    try:
        meta = json.loads((folder / "row.json").read_text())
        if meta.get("key") != key:
            return None
        with np.load(folder / "result.npz") as z:
            return {"meta": meta, **{k: z[k] for k in z.files}}
    except (OSError, ValueError, KeyError):
        return None


def run(design: Design, out: Path, eng: Engine | None, progress=None) -> list[dict]:
    """Compute (or reuse) every row; returns their results in :func:`rows` order."""
    todo = rows(design, eng.name if eng else None)
    variants = {v.id: v for v in design.plan.variants}
    prepared: dict = {}
    results, t0, fresh = [], time.perf_counter(), 0
    if design.stereo:
        from glsim.workflows.design import stereo
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
            elif row.kind.endswith(RESOLUTION):
                # the sweep is 2-D on camera 0: a stereo engine lends its planar one
                arrays = resolution.sweep_row(p.scene, p.camera, p.mesh, row.setting, row.noise_seed,
                                              design.resolution.periods_px, design.resolution.amplitude_px,
                                              eng.planar() if design.stereo else eng, folder, design.roi_margin)
            elif design.stereo:
                arrays = stereo.engine_row(prepared[pk], row.setting, row.noise_seed, eng, folder,
                                           rig_cameras(design, p.scene))
            else:
                arrays = engine_row(p, row.setting, row.noise_seed, eng, folder)
            folder.mkdir(parents=True, exist_ok=True)
            with io.atomic_path(folder / "result.npz") as tmp:
                with open(tmp, "wb") as f:
                    np.savez(f, **arrays)
            meta = {**row.meta(), "seconds": time.perf_counter() - t1}
            io.write_text(folder / "row.json", json.dumps(meta, indent=2))
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
