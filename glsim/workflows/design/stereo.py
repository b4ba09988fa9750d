"""Stereo design rows (engine pyvale3d): a stereo pair's images measured by a stereo DIC, against
glsim's exact truth in camera 0's frame (mm).

A stereo row renders both cameras at the reference state (step 0, the row's noise seed), at the
reference state again with another noise field (the static pair: its measured U, V, W are noise
alone) and at the deformed ``step``; the engine measures states 1 and 2 against state 0 on subsets
of camera 0's reference image. The truth at a subset centre is that of the material point seen at
that pixel of camera 0's reference image (a ray cast on the FE mesh, as ``glsim verify`` and truth
files' ``at(points)``): its reference position X, Y, Z and its displacement U, V, W at ``step``,
both in camera 0's frame, mm. The truth comes from the scene's exact cameras; the rig handed to
the engine (its calibration) is :func:`glsim.workflows.design.run.rig_cameras`'s.

The ROI is camera 0's specimen pixels at step 0 and at ``step`` whose material point camera 1
also sees inside its own specimen pixels at both steps (each mask eroded by the ROI margin;
occlusion by the specimen itself is not checked).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy import ndimage

from glsim.errors import GlsimError
from glsim.io.calibfiles import pyvale_calibration
from glsim.io.fe import specimen_mesh
from glsim.io.truth import mesh_geometry
from glsim.render import Renderer
from glsim.scene import Scene
from glsim.scene.camera import Camera, project_camera_frame, to_camera
from glsim.scene.locate import points_truth
from glsim.workflows.design import quick, strain as strainmod
from glsim.workflows.design.engine import StereoEngine, write_stereo_exchange
from glsim.workflows.design.planar import Prepared, static_seed
from glsim.workflows.design.stats import median, pct, rms
from glsim.workflows.design.spec import DicSetting

AXES = ("X", "Y", "Z")
DISPLACEMENTS = ("U", "V", "W")


@dataclasses.dataclass(frozen=True)
class StereoPrepared:
    """A set-up with one speckle pattern, ready for stereo rows: camera 0's :class:`Prepared`
    (noise-free reference image and variance for the quick rows, the stereo ROI) and camera 1."""
    base: Prepared
    camera1: str


def _world(X_cam: np.ndarray, cam: Camera) -> np.ndarray:
    """Camera frame → world (X_cam = R·X + t)."""
    return (X_cam - np.asarray(cam.translation)) @ np.asarray(cam.rotation)


def seen_by(cam0: Camera, cam1: Camera, mesh, pixels: np.ndarray, masks1: dict[int, np.ndarray]) -> np.ndarray:
    """Per camera-0 pixel (n, 2): is its material point inside camera 1's mask at every step of ``masks1``?"""
    g = mesh_geometry(mesh)
    ok = np.ones(len(pixels), bool)
    for step, mask in masks1.items():
        t = points_truth(g, cam0, pixels, step)
        uv, good = project_camera_frame(to_camera(_world(np.nan_to_num(t.X_deformed), cam0), cam1), cam1)
        c = np.rint(uv).astype(np.int64)
        H, W = mask.shape
        inside = good & t.valid & (c[:, 0] >= 0) & (c[:, 0] < W) & (c[:, 1] >= 0) & (c[:, 1] < H)
        hit = np.zeros(len(pixels), bool)
        hit[inside] = mask[c[inside, 1], c[inside, 0]]
        ok &= hit
    return ok


def prepare(scene: Scene, cameras: tuple[str, str], step: int, margin: int, mesh=None) -> StereoPrepared:
    """Render both cameras' noise-free states 0 and ``step`` (masks), camera 0's reference image
    and variance; the stereo ROI (module doc). ``mesh``: the specimen's (default the scene's own)."""
    c0, c1 = cameras
    mesh = specimen_mesh(scene) if mesh is None else mesh
    with Renderer(scene.replace(noise=None), mesh=mesh) as r:
        out = {(c, k): r.render(c, k, truth=True) for c in cameras for k in (0, step)}
        reference = r.reference
    erode = (lambda m: ndimage.binary_erosion(m, iterations=margin)) if margin else (lambda m: m)  # noqa: E731
    roi = erode(out[c0, 0].truth.mask & out[c0, step].truth.mask)
    rows, cols = np.nonzero(roi)
    if len(rows):
        masks1 = {k: erode(out[c1, k].truth.mask) for k in (0, step)}
        keep = seen_by(scene.camera(c0), scene.camera(c1), mesh, np.stack([cols, rows], 1).astype(float), masks1)
        roi = np.zeros_like(roi)
        roi[rows[keep], cols[keep]] = True
    if not roi.any():
        raise GlsimError(f"cameras {c0}, {c1}: no pixel of {c0} sees a point of the specimen that {c1} sees too at "
                         f"steps 0 and {step} (ROI margin {margin} px) — point both cameras at the specimen or "
                         "lower roi_margin")
    cam = scene.camera(c0)
    table = None
    if scene.noise is not None and scene.noise.model == "heteroscedastic":
        from glsim.effects import noise as noisemod
        table = noisemod.load_variance_table(scene.resolve(scene.noise.variance_file), cam.bit_depth)
    image = np.asarray(out[c0, 0].image, np.float64)
    base = Prepared(scene, c0, step, mesh, reference, image,
                    quick.pixel_variance(image, scene.noise, cam.bit_depth, table), roi)
    return StereoPrepared(base, c1)


def truth_mm(prep: StereoPrepared, x: np.ndarray, y: np.ndarray) -> dict[str, np.ndarray]:
    """Exact truth at camera-0 subset centres: reference position X, Y, Z and displacement U, V, W
    at the row's step (mm, camera 0's frame), the mm per px there (Z/√(fx·fy)), valid."""
    p = prep.base
    cam = p.scene.camera(p.camera)
    t = points_truth(mesh_geometry(p.mesh), cam, np.stack([x, y], axis=1).astype(np.float64), p.step)
    d = t.X_deformed - t.X_undeformed
    out = {f"truth_{a}": t.X_undeformed[:, j] for j, a in enumerate(AXES)}
    out.update({f"truth_{a}": d[:, j] for j, a in enumerate(DISPLACEMENTS)})
    out["scale"] = t.X_undeformed[:, 2] / math.sqrt(cam.fx * cam.fy)
    out["truth_valid"] = t.valid
    return out


def noisy_pairs(prep: StereoPrepared, noise_seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(cam0, cam1) reference, static, deformed] as the cameras write them (quantised), full scale."""
    p = prep.base
    pairs = []
    for seed, step in ((noise_seed, 0), (static_seed(noise_seed), 0), (noise_seed, p.step)):
        with Renderer(p.scene.replace(seed=seed), mesh=p.mesh, reference=p.reference) as r:
            pairs.append(tuple(np.asarray(r.render(c, step, quantize=True).image, np.float64)
                               / float(2 ** p.scene.camera(c).bit_depth - 1) for c in (p.camera, prep.camera1)))
    return pairs


def state_pairs(prep: StereoPrepared, noise_seed: int | None, steps) -> list[tuple[np.ndarray, np.ndarray]]:
    """[(cam0, cam1)] of each of ``steps`` under one noise seed (None: noise-free), quantised, full scale."""
    p = prep.base
    scene = p.scene.replace(noise=None) if noise_seed is None else p.scene.replace(seed=int(noise_seed))
    full = [float(2 ** p.scene.camera(c).bit_depth - 1) for c in (p.camera, prep.camera1)]
    with Renderer(scene, mesh=p.mesh, reference=p.reference) as r:
        return [tuple(np.asarray(r.render(c, k, quantize=True).image, np.float64) / f
                      for c, f in zip((p.camera, prep.camera1), full)) for k in steps]


def search_reach(prep: StereoPrepared) -> int:
    """How far pyvale's initial FFT search looks (px): the largest image motion of the ROI's
    material points (a sample) between the states in either camera, × 1.5 + 4, at least 16."""
    p = prep.base
    ys, xs = np.nonzero(p.roi)
    k = max(1, len(xs) // 200)
    cam0 = p.scene.camera(p.camera)
    t = points_truth(mesh_geometry(p.mesh), cam0, np.stack([xs[::k], ys[::k]], 1).astype(float), p.step)
    reach = 0.0
    for cam in (cam0, p.scene.camera(prep.camera1)):
        (a, ok_a), (b, ok_b) = (project_camera_frame(to_camera(_world(np.nan_to_num(X), cam0), cam), cam)
                                for X in (t.X_undeformed, t.X_deformed))
        ok = t.valid & ok_a & ok_b
        reach = max(reach, float(np.max(np.abs(b - a)[ok], initial=0.0)))
    return max(16, int(math.ceil(1.5 * reach)) + 4)


def engine_row(prep: StereoPrepared, setting: DicSetting, noise_seed: int, eng: StereoEngine, folder,
               rig: tuple[Camera, Camera]) -> dict[str, np.ndarray]:
    """One stereo row: render, write the exchange (the rig ``rig`` as its calibration), measure,
    and the truth at the engine's centres."""
    pairs = noisy_pairs(prep, noise_seed)
    write_stereo_exchange(folder / "exchange", pairs, prep.base.roi, pyvale_calibration(*rig),
                          setting.subset_size, setting.subset_step, setting.shape_function, search_reach(prep),
                          strain=setting.strain)
    m = eng.measure(folder / "exchange")
    if m.X.shape[0] != 3:
        raise GlsimError(f"engine {eng.name}: {m.X.shape[0]} states measured, expected 3 (reference, static, deformed)")
    out = {"x": m.x, "y": m.y, "engine_seconds": np.float64(m.seconds), "engine_version": np.str_(m.version)}
    for name, k in (("ref", 0), ("static", 1), ("", 2)):
        pre = f"{name}_" if name else ""
        for a in (*AXES, *DISPLACEMENTS):
            out[pre + a] = getattr(m, a)[k]
        out[pre + "valid"] = m.valid[k]
    out["cost"] = m.cost[2]
    out["roi_bits"] = np.packbits(prep.base.roi)
    out["roi_shape"] = np.array(prep.base.roi.shape, np.int64)
    if setting.strain is not None:   # states 1 (static) and 2 (deformed)
        out.update(strainmod.row_arrays(m, lambda x, y, f: strainmod.surface_truth(
            lambda a, b: _points(prep, a, b), x, y, f), setting.strain_formulation, static=1, deformed=2))
    return {**out, **truth_mm(prep, m.x, m.y)}


def _points(prep: StereoPrepared, x: np.ndarray, y: np.ndarray):
    """Material points seen at camera-0 pixels: reference position, displacement (mm, camera 0's
    frame), valid — the surface strain's truth field."""
    p = prep.base
    t = points_truth(mesh_geometry(p.mesh), p.scene.camera(p.camera), np.stack([x, y], axis=1), p.step)
    return t.X_undeformed, t.X_deformed - t.X_undeformed, t.valid


# ---- summaries --------------------------------------------------------------------------------------


def _std(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.std(a)) if a.size else math.nan


def row_summary(r: dict) -> dict:
    """One stereo row's own figures (rows.csv)."""
    ok = r["valid"] & r["truth_valid"]
    e = {a: np.where(ok, r[a] - r[f"truth_{a}"], np.nan) for a in DISPLACEMENTS}
    s = r["static_valid"]
    return {"n_subsets": int(len(r["x"])), "valid_share": float(np.mean(r["valid"])) if len(ok) else math.nan,
            "p95_abs_error_mm": pct(np.sqrt(e["U"] ** 2 + e["V"] ** 2 + e["W"] ** 2)),
            "p95_abs_W_mm": pct(np.abs(e["W"])),
            **{f"mean_{a}_error_mm": float(np.nanmean(e[a])) if ok.any() else math.nan for a in DISPLACEMENTS},
            **{f"static_std_{a}_mm": _std(r[f"static_{a}"][s]) for a in DISPLACEMENTS},
            "engine_seconds": round(float(r["engine_seconds"]), 3)}


def stack(rows: list[dict], keys) -> dict | None:
    """Rows of one (set-up, setting) on their common subset centres: (realisations, n) per key."""
    if not rows:
        return None
    rounded = [list(zip(np.round(r["x"], 3), np.round(r["y"], 3))) for r in rows]
    common = sorted(set.intersection(*map(set, rounded)))
    idx = []
    for xy in rounded:
        where = {c: i for i, c in enumerate(xy)}
        idx.append(np.array([where[c] for c in common], np.int64))
    return {"x": np.array([c[0] for c in common], np.float64), "y": np.array([c[1] for c in common], np.float64),
            **{k: np.stack([r[k][i] for r, i in zip(rows, idx)]) for k in keys}}


def _bias_noise(err: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per subset: mean and std (ddof = 1) over realisations of ``err`` where ``ok``; NaN where too few."""
    e = np.where(ok, err, np.nan)
    n = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        bias = np.where(n > 0, np.nansum(e, 0) / n, np.nan)
        noise = np.sqrt(np.nansum((e - bias) ** 2, 0) / (n - 1))
    noise[n < 2] = np.nan
    return bias, noise


KEYS = ("valid", "ref_valid", "static_valid", "truth_valid", "scale",
        *AXES, *DISPLACEMENTS, *(f"ref_{a}" for a in AXES), *(f"static_{a}" for a in (*AXES, *DISPLACEMENTS)),
        *(f"truth_{a}" for a in (*AXES, *DISPLACEMENTS)))


def aggregate(rows: list[dict]) -> tuple[dict, dict]:
    """Figures of merit and maps of one (set-up, setting) from its stereo rows (realisations):
    bias (mean − truth) and noise (std) maps of X, Y, Z (the reference state's shape) and U, V, W
    (the deformed state), the static pair's noise floor, the valid share."""
    st = stack(rows, KEYS)
    ok, ok0 = st["valid"] & st["truth_valid"], st["ref_valid"] & st["truth_valid"]
    maps, summary = {"x": st["x"], "y": st["y"]}, {}
    for a in AXES:
        maps[f"bias_{a}"], maps[f"noise_{a}"] = _bias_noise(st[f"ref_{a}"] - st[f"truth_{a}"], ok0)
    for a in DISPLACEMENTS:
        maps[f"bias_{a}"], maps[f"noise_{a}"] = _bias_noise(st[a] - st[f"truth_{a}"], ok)
    e = {a: np.where(ok, st[a] - st[f"truth_{a}"], np.nan) for a in DISPLACEMENTS}
    bias3 = np.sqrt(sum(maps[f"bias_{a}"] ** 2 for a in DISPLACEMENTS))
    noise3 = np.sqrt(sum(maps[f"noise_{a}"] ** 2 for a in DISPLACEMENTS) / 3)
    s = st["static_valid"]
    floor = {a: _std(st[f"static_{a}"][s]) for a in DISPLACEMENTS}
    # each state is triangulated with its own noise: the static state's position minus the reference
    # state's is the difference of two draws, √2 × one's spread
    both = s & st["ref_valid"]
    floor.update({a: _std((st[f"static_{a}"] - st[f"ref_{a}"])[both]) / math.sqrt(2) for a in AXES})
    summary.update(
        realisations=int(len(st["valid"])), subsets=int(len(st["x"])), valid_share=float(st["valid"].mean()),
        p95_abs_error_mm=pct(np.sqrt(e["U"] ** 2 + e["V"] ** 2 + e["W"] ** 2)),
        p95_abs_W_mm=pct(np.abs(e["W"])),
        p95_abs_Z_mm=pct(np.abs(np.where(ok0, st["ref_Z"] - st["truth_Z"], np.nan))),
        rms_bias_mm=rms(bias3), rms_bias_W_mm=rms(maps["bias_W"]), rms_bias_Z_mm=rms(maps["bias_Z"]),
        median_noise_mm=median(noise3), median_noise_W_mm=median(maps["noise_W"]),
        median_noise_Z_mm=median(maps["noise_Z"]),
        noise_floor_mm=math.sqrt(sum(floor[a] ** 2 for a in DISPLACEMENTS) / 3),
        noise_floor_inplane_mm=math.sqrt((floor["U"] ** 2 + floor["V"] ** 2) / 2),
        **{f"noise_floor_{a}_mm": floor[a] for a in (*DISPLACEMENTS, *AXES)},
        mm_per_px=median(np.nanmean(st["scale"], axis=0)))
    roi = rows[0].get("roi_bits")
    if roi is not None:
        shape = tuple(int(v) for v in rows[0]["roi_shape"])
        maps["roi"] = np.unpackbits(roi, count=shape[0] * shape[1]).reshape(shape).astype(bool)
    return summary, maps
