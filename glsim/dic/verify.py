"""`glsim verify`: glsim's bulge images measured by an independent stereo DIC (pyvale).

The paper's §3 verification, repeated with an open DIC: glsim renders the bulge stereo pair
(reference state, step 0, and the 5 mm bulge, step 1; mode ``exact``, no noise, no lighting,
no blur), writes an exchange folder (16-bit and 8-bit TIFF images, ROI mask, pyvale
calibration, truth maps; JSON/npz/TIFF only), runs ``verify/dic.py`` in its own environment
(``.venv-verify``, which never imports glsim) and compares the measured coordinates at the
DIC's subset centres with the imposed ones, as the paper's Tables 4 and 5.

Conventions: mm; pixels with centres at integers; glsim's camera 0 (``cameras[0]``, the world
frame) is pyvale's camera 0, glsim's camera 1 pyvale's camera 1; pyvale's stereo extrinsics
are X_cam1 = Rz(psi)·Ry(phi)·Rx(theta)·X_cam0 + T (degrees, mm), the same convention as
glsim's ``stereo`` pose. Differences in px are mm / M with M = mean Z / √(fx·fy) (mm per px)
over the compared subset centres in the reference state.

    glsim verify run [--size W H] [--exchange build/verify] [--results bench/results]
    glsim verify compare EXCHANGE [--results DIR]
"""
from __future__ import annotations

import datetime
import json
import math
import subprocess
import time
from pathlib import Path

import numpy as np
import tifffile
from scipy import ndimage

from glsim.io import images as io
from glsim.io.calibfiles import pyvale_calibration
from glsim.bench.report import gl_info, machine_info
from glsim.bench.formatting import num
from glsim.scene.bilinear import bilinear
from glsim.scene.camera import Camera, to_camera
from glsim.errors import GlsimError
from glsim.io.fe import specimen_mesh
from glsim.io.npzfile import NpzError, read_npz
from glsim.imaging.reference import Reference, make_reference
from glsim.render import Renderer, Truth
from glsim.scene import Bulge, Scene, bulge_scene
from glsim.workflows.pyvale_env import PYTHON as DIC_PYTHON, STEREO_SCRIPT as DIC_SCRIPT

FORMAT = "glsim-verify/1"

FULL_SIZE = (1624, 1234)      # paper Table 3
DEFORMED_STEP = 1             # bulge_scene(steps=1): step 1 is the full 5 mm bulge
MESH_DIVISIONS = 32           # n_core = n_ring of the built-in disc mesh (default 8)
SPECKLE_SIGMA_PX = 1.0        # Gaussian low-pass of the speckle, camera-0 pixels
ROI_RADIUS_MM = 45.0          # ROI: material points within this radius of the plate centre
SEED = 0                      # speckle seed
BIT_DEPTHS = (16, 8)

# pyvale.dic.calculate_3d keyword arguments common to every run: paper Table 3 (subset 19,
# step 9, B-spline) with pyvale's 5×5 Gaussian prefilter off; optimiser tolerance 1e-4 (relative
# parameter and cost change; 1e-3, its default, gives the same affine results) and 100 iterations.
CALCULATE_3D = {"subset_size": 19, "subset_step": 9, "correlation_criteria": "ZNSSD",
                "interpolation_routine": "BSPLINE", "image_filter_kernel": 1,
                "precision": 1e-4, "max_iterations": 100, "threshold": 0.9,
                "output_below_threshold": True}
# Table 3 (affine, 16-bit), the same with the quadratic shape function, and with 8-bit images.
RUNS = ({"name": "table3", "shape_function": "AFFINE", "bit_depth": 16},
        {"name": "quadratic", "shape_function": "QUAD", "bit_depth": 16},
        {"name": "table3-8bit", "shape_function": "AFFINE", "bit_depth": 8})

AXES = ("X", "Y", "Z")
DISPLACEMENTS = ("U", "V", "W")
GOAL_PX = {"mean": 1e-3, "std": 5e-3}
# Paper Tables 4 and 5 (MatchID on 8-bit images): mean and std of DIC − imposed, px.
PAPER_PX = {"undeformed": {"X": (-2.18e-03, 1.40e-03), "Y": (2.49e-05, 2.69e-03), "Z": (8.34e-03, 9.31e-03)},
            "deformed": {"X": (-2.09e-04, 5.26e-03), "Y": (5.09e-06, 3.90e-03), "Z": (8.09e-03, 1.58e-02)}}


# ---- scene ------------------------------------------------------------------------------------
def verify_scene(size=FULL_SIZE, mesh_divisions: int = MESH_DIVISIONS) -> Scene:
    """The paper's bulge stereo rig (Tables 2–3), reference state and one 5 mm bulge step, on a
    disc mesh of ``mesh_divisions`` core and ring divisions; exact mode, 1 sample per pixel,
    cubic B-spline reference interpolation, no lighting, blur or noise."""
    scene = bulge_scene(size=tuple(size), steps=DEFORMED_STEP, backend="gl", mode="exact",
                        interpolation="bspline3", samples_per_pixel=1, precision="fp64")
    bulge = Bulge(steps=DEFORMED_STEP, n_core=mesh_divisions, n_ring=mesh_divisions)
    return scene.replace(specimen={"bulge": bulge}, speckle={"seed": SEED})


def smoothed_reference(scene: Scene, mesh, sigma_px: float) -> Reference:
    """The scene's generated speckle low-passed by a Gaussian of ``sigma_px`` camera-0 pixels.

    The built-in dots have 1-px edges: sampled at pixel centres they alias, and a DIC that
    interpolates the images cannot match them to 1e-3 px. The paper's pattern had "smooth
    gradients" too. The result has no ``dots`` (it is no longer the Boolean model).
    """
    ref = make_reference(scene, mesh)
    if sigma_px <= 0:
        return ref
    sigma = sigma_px * scene.speckle.oversample   # reference pixels per camera-0 pixel
    image = ndimage.gaussian_filter(ref.image.astype(np.float64), sigma, mode="nearest")
    return Reference(image.astype(np.float32), ref.camera)


# ---- calibration in pyvale's convention ----------------------------------------------------------


# ---- truth, ROI and exchange folder ------------------------------------------------------------
def material_positions(mesh, truth: Truth, step: int, cam1: Camera) -> np.ndarray:
    """(H, W, 3) mm in camera 0's frame: where the material point seen at each pixel of
    ``truth`` (a step-0 render) is at ``step``; NaN off the specimen."""
    out = np.full(truth.mask.shape + (3,), np.nan)
    m = truth.mask
    q = mesh.quads[truth.element[m]]
    out[m] = to_camera(bilinear(mesh.deformed(step)[q], truth.xi[m], truth.eta[m]), cam1)
    return out


def roi_mask(truth: Truth, scene: Scene, radius_mm: float) -> np.ndarray:
    """Pixels whose undeformed material point lies within ``radius_mm`` of the plate axis.

    The specimen pose maps plate coordinates to the world: X = R·x + t; camera 0 is the world.
    """
    sp = scene.specimen
    X = np.where(truth.mask[..., None], truth.X_undeformed, 0.0)
    cam1 = scene.cameras[0]
    world = (X - cam1.translation) @ cam1.rotation          # camera 0 → world
    local = (world - np.asarray(sp.t)) @ np.asarray(sp.R)   # world → plate (Rᵀ·(X − t))
    return truth.mask & (np.hypot(local[..., 0], local[..., 1]) <= radius_mm)


def seed_point(roi: np.ndarray) -> list[int]:
    """The ROI pixel nearest the ROI's centroid, [x, y] px (the DIC's reliability-guided seed)."""
    rows, cols = np.nonzero(roi)
    i = np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2)
    return [int(cols[i]), int(rows[i])]


def image_name(camera: int, step: int, bits: int) -> str:
    """Exchange-folder image name; ``cam0`` is camera 0 of glsim and of pyvale."""
    return f"cam{camera}_{step:04d}_{bits}bit.tif"


def write_exchange(out: str | Path, size=FULL_SIZE, mesh_divisions: int = MESH_DIVISIONS,
                   sigma_px: float = SPECKLE_SIGMA_PX, roi_radius_mm: float = ROI_RADIUS_MM,
                   backend: str = "gl", runs=RUNS) -> Path:
    """Render the bulge pair and write the exchange folder; returns ``manifest.json``'s path.

    Files: ``cam{0,1}_{step}_{16,8}bit.tif``, ``roi.tif`` (uint8 0/255 on camera 0's
    reference image), ``calibration.json`` (pyvale's ``Calib``), ``truth.npz`` (``mask`` and
    ``X_step{k}``: (H, W, 3) mm, camera 0's frame, the material point seen at each reference
    pixel at step k), ``scene.json`` and ``manifest.json`` (written last).
    """
    out = Path(out)
    scene = verify_scene(size, mesh_divisions)
    mesh = specimen_mesh(scene)
    t0 = time.perf_counter()
    with Renderer(scene, backend=backend, mesh=mesh, reference=smoothed_reference(scene, mesh, sigma_px)) as r:
        states = []
        for step in (0, DEFORMED_STEP):
            images = {str(b): [image_name(c, step, b) for c in (0, 1)] for b in BIT_DEPTHS}
            for c in (0, 1):
                res = r.render(c, step, truth=(c, step) == (0, 0))
                for b in BIT_DEPTHS:
                    io.write_image(out / image_name(c, step, b), res.image, b)
                if res.truth is not None:
                    truth = res.truth
            states.append({"step": step, "label": "undeformed" if step == 0 else "deformed", "images": images})
        machine = machine_info(gl_info(r))
    seconds = time.perf_counter() - t0
    roi = roi_mask(truth, scene, roi_radius_mm)
    maps = {f"X_step{s['step']}": material_positions(mesh, truth, s["step"], scene.cameras[0]) for s in states}
    io.write_truth(out / "truth.npz", {"mask": truth.mask, **maps})
    with io.atomic_path(out / "roi.tif") as tmp:
        tifffile.imwrite(tmp, roi.astype(np.uint8) * 255, photometric="minisblack")
    io.write_text(out / "calibration.json", json.dumps(pyvale_calibration(*scene.cameras[:2]), indent=2))
    io.write_text(out / "scene.json", scene.to_json())
    manifest = {"format": FORMAT, "size": list(scene.cameras[0].size), "states": states,
                "roi": "roi.tif", "seed": seed_point(roi), "calibration": "calibration.json",
                "truth": "truth.npz", "scene": "scene.json", "calculate_3d": CALCULATE_3D,
                "runs": list(runs), "mesh_divisions": mesh_divisions, "speckle_sigma_px": sigma_px,
                "roi_radius_mm": roi_radius_mm, "backend": backend, "render_seconds": seconds,
                "machine": machine}
    return io.write_text(out / "manifest.json", json.dumps(manifest, indent=2))


def run_dic(exchange: str | Path, python: str | Path = DIC_PYTHON, script: str | Path = DIC_SCRIPT) -> None:
    """Run ``verify/dic.py EXCHANGE`` with the pyvale environment's interpreter, in EXCHANGE."""
    for path, what in ((python, "the pyvale environment's python (make verify creates .venv-verify)"),
                       (script, "verify/dic.py (it lives in the source checkout, not in the wheel)")):
        if not Path(path).exists():
            raise GlsimError(f"{path} not found: {what}; give it with --python / --script")
    # cwd: pyvale writes plotter_log.log into its working directory when imported.
    exchange = Path(exchange).resolve()
    done = subprocess.run([str(Path(python).absolute()), str(Path(script).resolve()), str(exchange)], cwd=exchange)
    if done.returncode != 0:
        raise GlsimError(f"{script} failed with exit status {done.returncode} (its output is above)")


# ---- comparison ---------------------------------------------------------------------------------
def sample_bilinear(maps: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation of (H, W, C) ``maps`` at (n, 2) pixel coordinates (u, v) →
    ((n, C) values, (n,) valid). Valid where every neighbour with a non-zero weight is finite
    and inside the image; exact at integer coordinates."""
    H, W = maps.shape[:2]
    uv = np.asarray(uv, dtype=np.float64)
    i0 = np.floor(uv).astype(int)
    f = uv - i0
    values = np.zeros((len(uv), maps.shape[2]))
    valid = np.ones(len(uv), dtype=bool)
    for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):
        w = (f[:, 0] if du else 1 - f[:, 0]) * (f[:, 1] if dv else 1 - f[:, 1])
        u, v = i0[:, 0] + du, i0[:, 1] + dv
        inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        m = maps[np.clip(v, 0, H - 1), np.clip(u, 0, W - 1)]
        ok = inside & np.all(np.isfinite(m), axis=1)
        valid &= ok | (w == 0)
        values += w[:, None] * np.where(ok[:, None], m, 0.0)
    return np.where(valid[:, None], values, np.nan), valid


def difference_rows(measured: np.ndarray, imposed: np.ndarray, mm_per_px: float, names=AXES) -> list[dict]:
    """Tables 4/5 rows: per component, mean and (population) std of measured − imposed in mm
    and in px (mm / ``mm_per_px``), and the largest |difference| in px."""
    d = np.asarray(measured, np.float64) - np.asarray(imposed, np.float64)
    rows = []
    for j, name in enumerate(names):
        mean, std = float(np.mean(d[:, j])), float(np.std(d[:, j]))
        rows.append({"dir": name, "mean_mm": mean, "std_mm": std, "mean_px": mean / mm_per_px,
                     "std_px": std / mm_per_px, "max_abs_px": float(np.max(np.abs(d[:, j]))) / mm_per_px})
    return rows


def compare(exchange: str | Path, run: dict) -> dict:
    """One DIC run's Tables 4/5 against the truth maps, on the subsets valid in every state."""
    exchange = Path(exchange)
    manifest = json.loads((exchange / "manifest.json").read_text())
    truth_path = exchange / str(manifest["truth"])
    if not _inside(truth_path, exchange):
        raise GlsimError(f"{exchange / 'manifest.json'}: truth {manifest['truth']!r} lies outside the exchange folder "
                         "— write the exchange again (glsim verify run)")
    steps = [s["step"] for s in manifest["states"]]
    try:   # each array bounded by its header before it is made (pyvale's results, glsim's truth)
        truth = read_npz(truth_path, [f"X_step{k}" for k in steps])
        meas = read_npz(exchange / f"measured_{run['name']}.npz",
                        ("ss_x", "ss_y", "valid", "X", "U", "seconds", "pyvale_version"))
    except (NpzError, OSError) as exc:
        raise GlsimError(f"glsim verify: {exc} — run the DIC again (glsim verify run)") from None
    uv = np.stack([meas["ss_x"], meas["ss_y"]], axis=1).astype(np.float64)
    imposed, ok = {}, np.all(meas["valid"], axis=0)
    for s in manifest["states"]:
        imposed[s["step"]], valid = sample_bilinear(truth[f"X_step{s['step']}"], uv)
        ok &= valid
    cam0 = json.loads((exchange / manifest["calibration"]).read_text())["cam0"]
    ref = imposed[0][ok]
    mm_per_px = float(np.mean(ref[:, 2]) / math.sqrt(cam0["fx"] * cam0["fy"]))
    states = []
    for i, s in enumerate(manifest["states"]):
        rows = difference_rows(meas["X"][i][ok], imposed[s["step"]][ok], mm_per_px)
        if s["step"] != 0:
            rows += difference_rows(meas["U"][i][ok], imposed[s["step"]][ok] - ref, mm_per_px, DISPLACEMENTS)
        for row in rows:
            row["paper_mean_px"], row["paper_std_px"] = PAPER_PX[s["label"]].get(row["dir"], (None, None))
            row["goal_met"] = abs(row["mean_px"]) <= GOAL_PX["mean"] and row["std_px"] <= GOAL_PX["std"]
        states.append({"label": s["label"], "step": s["step"], "rows": rows})
    return {**run, "n_subsets": int(len(uv)), "n_compared": int(ok.sum()), "mm_per_px": mm_per_px,
            "dic_seconds": float(meas["seconds"]), "pyvale": str(meas["pyvale_version"]), "states": states}


# ---- report -----------------------------------------------------------------------------------
def results_markdown(res: dict) -> str:
    """The results as markdown: settings, then one Tables 4/5 block per DIC run."""
    m = res["machine"]
    lines = ["# glsim verification with an independent stereo DIC (pyvale)", "",
             f"- Machine: `{m['node']}`, {m['cpu']}, {m['cores']} cores; GL: {m['gl']['renderer']}",
             f"- Date: {res['date']}; images {res['size'][0]}×{res['size'][1]}, bulge disc mesh "
             f"{res['mesh_divisions']}×{res['mesh_divisions']} divisions, speckle low-passed σ = "
             f"{res['speckle_sigma_px']} px, ROI r ≤ {res['roi_radius_mm']} mm, render (4 images + truth) "
             f"{res['render_seconds']:.1f} s",
             f"- DIC: pyvale {res['runs'][0]['pyvale']} `calculate_3d` with "
             + ", ".join(f"`{k}={v}`" for k, v in res["calculate_3d"].items()),
             "- Differences are DIC − imposed at the subset centres, camera 0's frame; std is the "
             "population std; px = mm / M, M = mean Z / √(fx·fy) over the compared subset centres in "
             "the reference state (mm per px)",
             f"- Goal: |mean| ≤ {GOAL_PX['mean']:.0e} px and std ≤ {GOAL_PX['std']:.0e} px; paper: "
             "Tables 4–5 (MatchID, 8-bit images)", ""]
    for run in res["runs"]:
        lines += [f"## {run['name']}: {run['shape_function'].lower()} shape function, {run['bit_depth']}-bit images",
                  "", f"{run['n_compared']} of {run['n_subsets']} subsets compared (converged and ZNCC ≥ "
                  f"{res['calculate_3d']['threshold']} in both states); M = {run['mm_per_px']:.5f} mm/px; "
                  f"DIC {run['dic_seconds']:.1f} s", "",
                  "| state | dir | mean (mm) | std (mm) | mean (px) | std (px) | max abs (px) | goal | paper mean (px) | paper std (px) |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for s in run["states"]:
            for r in s["rows"]:
                lines.append(f"| {s['label']} | {r['dir']} | {num(r['mean_mm'], '.2e')} | {num(r['std_mm'], '.2e')} | "
                             f"{num(r['mean_px'], '.2e')} | {num(r['std_px'], '.2e')} | {num(r['max_abs_px'], '.2e')} | "
                             f"{'yes' if r['goal_met'] else 'no'} | {num(r['paper_mean_px'], '.2e')} | {num(r['paper_std_px'], '.2e')} |")
        lines.append("")
    return "\n".join(lines)


def report(exchange: str | Path, results_dir: str | Path) -> dict:
    """Compare every run of the exchange folder and write ``verify.json`` and ``verify.md``."""
    manifest = json.loads((Path(exchange) / "manifest.json").read_text())
    keys = ("size", "mesh_divisions", "speckle_sigma_px", "roi_radius_mm", "render_seconds",
            "machine", "calculate_3d", "backend")
    res = {"date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
           **{k: manifest[k] for k in keys}, "goal_px": GOAL_PX, "paper_px": PAPER_PX,
           "runs": [compare(exchange, run) for run in manifest["runs"]]}
    results_dir = Path(results_dir)
    io.write_text(results_dir / "verify.json", json.dumps(res, indent=2))
    io.write_text(results_dir / "verify.md", results_markdown(res))
    return res


# ---- command line -------------------------------------------------------------------------------


def _inside(path: Path, folder: Path) -> bool:
    return Path(path).resolve().is_relative_to(Path(folder).resolve())
