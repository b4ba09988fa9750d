"""Rigid-body sweep (the DIC S-curve): scene, exactly shifted model images, exchange folder, analysis.

**Sweep.** A flat plate square to one camera (512×512 px, 0.1 mm/px at 300 mm, the plate
480 × 420 px) is translated along the image x axis by 0.0, 0.1, …, 1.0 px (converted to mm
with the camera's scale at the plate). Each sequence is rendered by glsim (modes fast, q4 and
exact with cubic B-spline interpolation; exact with ``interpolation = "procedural"``, the
Boolean speckle evaluated at every sample) and, as the bias-free reference, built directly
from the speckle model: :func:`glsim.scene.speckle.evaluate` at the exactly shifted reference
coordinates of every sample (the pixel's ray met with the plate's plane in float64, the shift
removed, projected into the reference camera), box-filtered as the renderer does. The
images go, 16-bit, into an exchange folder; ``verify/dic2d.py`` (in ``.venv-verify``, no
glsim) measures each sequence with pyvale's 2-D DIC; this module compares the measured
displacements with the imposed shifts: bias (mean of measured − imposed over the subsets)
and its std versus the sub-pixel shift, per sequence, and the paired difference to the model
sequence at the same subsets (the generator's own share of the error).

The report (figure, markdown) is :mod:`glsim.dic.sweep_report`, the accuracy–time
frontier :mod:`glsim.dic.frontier`.

    glsim verify sweep [--exchange build/sweep] [--results bench/results] [--backend gl]
    glsim verify sweep-compare EXCHANGE [--results bench/results]
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

from glsim.bench.report import gl_info, machine_info
from glsim.io import images as io
from glsim.scene import speckle
from glsim.scene.camera import Camera, pixel_rays, project_camera_frame, to_camera
from glsim.errors import GlsimError
from glsim.io.fe import specimen_mesh
from glsim.io.npzfile import NpzError, read_npz
from glsim.imaging.reference import Reference, camera_scale
from glsim.render import Renderer
from glsim.scene import Plate, Render, Scene, Specimen, Speckle
from glsim.workflows.pyvale_env import PLANAR_SCRIPT as DIC_SCRIPT, PYTHON as DIC_PYTHON

FORMAT = "glsim-sweep/1"
MIN_SIZE = 256  # px; at 160 px pyvale's calculate_2d writes empty results

SIZE = (512, 512)             # camera px
FX = 3000.0                   # px at SIZE[0]; 0.1 mm/px at DISTANCE
DISTANCE = 300.0              # mm, camera centre to plate
PLATE_MM = (48.0, 42.0)       # 480 × 420 px; not square, so the reference camera is axis-aligned
PLATE_ELEMENTS = (8, 7)
SHIFTS_PX = tuple(i / 10 for i in range(11))
SEED = 0
BIT_DEPTH = 16
APPARENT_STRIDE = 2          # apparent_shift fits every 2nd row and column of the ROI
ROI_MARGIN_PX = 4             # ROI: pixels covered at every shift, eroded by this many px

# The sequences: glsim renders (mode × interpolation × samples per pixel) and the model.
SEQUENCES = (
    {"name": "model", "source": "model", "mode": "-", "interpolation": "evaluate", "spp": 1},
    {"name": "exact-procedural", "source": "glsim", "mode": "exact", "interpolation": "procedural", "spp": 1},
    {"name": "exact-bspline3", "source": "glsim", "mode": "exact", "interpolation": "bspline3", "spp": 1},
    {"name": "q4-bspline3", "source": "glsim", "mode": "q4", "interpolation": "bspline3", "spp": 1},
    {"name": "fast-bspline3", "source": "glsim", "mode": "fast", "interpolation": "bspline3", "spp": 1},
    {"name": "model-spp4", "source": "model", "mode": "-", "interpolation": "evaluate", "spp": 4},
    {"name": "exact-procedural-spp4", "source": "glsim", "mode": "exact", "interpolation": "procedural", "spp": 4},
    {"name": "exact-bspline3-spp4", "source": "glsim", "mode": "exact", "interpolation": "bspline3", "spp": 4},
)
# pyvale.dic.calculate_2d keyword arguments common to every run: B-spline interpolation, ZNSSD,
# affine shape function, pyvale's 5×5 Gaussian prefilter off (as verify/dic.py), tolerance 1e-4.
CALCULATE_2D = {"subset_step": 10, "correlation_criteria": "ZNSSD", "shape_function": "AFFINE",
                "interpolation_routine": "BSPLINE", "image_filter_kernel": 1, "precision": 1e-4,
                "max_iterations": 100, "threshold": 0.9, "max_displacement": 16,
                "output_below_threshold": True}
RUNS = ({"name": "s21", "subset_size": 21}, {"name": "s31", "subset_size": 31})


# ---- scene and imposed shifts --------------------------------------------------------------------
def camera(size=SIZE) -> Camera:
    """The sweep camera: square onto the plate, no distortion, 16-bit; fx scales with the width."""
    W, H = size
    fx = FX * W / SIZE[0]
    return Camera(name="cam0", size=(W, H), fx=fx, fy=fx, cx=(W - 1) / 2, cy=(H - 1) / 2, bit_depth=BIT_DEPTH)


def mm_per_px(cam: Camera, distance: float = DISTANCE) -> float:
    """Camera scale (mm per px) on a fronto-parallel plane ``distance`` mm in front of it,
    :func:`glsim.imaging.reference.camera_scale` of a point on its axis: Z / √(fx·fy)."""
    return camera_scale(cam, np.array([[0.0, 0.0, distance]]))


def shifts_mm(shifts_px, scale: float) -> tuple[tuple[float, float, float], ...]:
    """Plate translations (mm, world = camera frame) for image shifts along +x of ``shifts_px``."""
    return tuple((float(s) * scale, 0.0, 0.0) for s in shifts_px)


def sweep_scene(size=SIZE, shifts_px=SHIFTS_PX, seed: int = SEED, spp: int = 1) -> Scene:
    """One camera square onto a 48 × 42 mm plate at 300 mm; step k is shift ``shifts_px[k]``
    (step 0 is the undeformed plate, so a shift of 0 is a separate, identical step)."""
    cam = camera(size)
    scale = mm_per_px(cam)
    w, h = (d * size[0] / SIZE[0] for d in PLATE_MM)
    plate = Plate(width=w, height=h, nx=PLATE_ELEMENTS[0], ny=PLATE_ELEMENTS[1],
                  translations=shifts_mm(shifts_px, scale))
    return Scene(cameras=(cam,), specimen=Specimen(plate=plate, t=(0.0, 0.0, DISTANCE)),
                 speckle=Speckle(seed=seed),
                 render=Render(mode="exact", interpolation="procedural", samples_per_pixel=spp))


# ---- the exactly shifted model images ------------------------------------------------------------
def model_image(scene: Scene, reference: Reference, translation, spp: int = 1,
                grid: speckle.DotGrid | None = None, dtype=np.float32,
                pixels: np.ndarray | None = None) -> np.ndarray:
    """The speckle model seen by camera 0 with the plate translated by ``translation`` (mm,
    world): for every sample of the s×s grid (the renderer's sample positions), the pixel's ray
    meets the plate's plane (float64), the translation is removed, the material point is
    projected into the reference camera and :func:`speckle.evaluate` gives the exact grey
    there; samples off the plate get the background; the samples are box-filtered.

    Returns (H, W) in ``dtype`` (float32 as the renderer's images; float64 for
    :func:`apparent_shift`), or with ``pixels`` (an (H, W) bool mask) only those pixels, in
    the order of ``image[pixels]``."""
    if reference.dots is None:
        raise GlsimError("the model images need the built-in speckle generator (reference.dots)")
    cam = scene.cameras[0]
    plate, sp = scene.specimen.plate, scene.specimen
    H, W = cam.height, cam.width
    s = math.isqrt(spp)
    rows, cols = np.nonzero(np.ones((H, W), bool) if pixels is None else pixels)
    # Sample i of pixel u at (u·s + i + 0.5)/s − 0.5, written as camera.pixel_grid does.
    k = np.arange(s)
    su = ((cols[:, None, None] * s + k[None, None, :]) + 0.5) / s - 0.5
    sv = ((rows[:, None, None] * s + k[None, :, None]) + 0.5) / s - 0.5
    samples = np.stack(np.broadcast_arrays(su, sv), axis=-1)          # (n, s, s, 2)
    d = np.asarray(translation, np.float64)
    R_sp, t_sp = np.asarray(sp.R, np.float64), np.asarray(sp.t, np.float64)
    # The plate's plane after the translation, in camera 0's frame: point P and normal n.
    P = to_camera(t_sp + d, cam)
    n = cam.rotation @ R_sp[:, 2]
    rays, ok = pixel_rays(samples, cam)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (P @ n) / (rays @ n)
    X_cam = rays * lam[..., None]
    X_world = (X_cam - cam.translation) @ cam.rotation          # camera → world
    X0 = X_world - d                                            # the undeformed material point
    local = (X0 - t_sp) @ R_sp                                  # world → plate
    on = ok & (lam > 0) & (np.abs(local[..., 0]) <= plate.width / 2) & (np.abs(local[..., 1]) <= plate.height / 2)
    uv, ref_ok = project_camera_frame(to_camera(X0, reference.camera), reference.camera)
    on &= ref_ok
    grey = np.full(on.shape, float(scene.render.background))
    grey[on] = speckle.evaluate(reference.dots, uv[on], grid)
    grey = grey.mean(axis=(1, 2)) if s > 1 else grey[:, 0, 0]
    return (grey if pixels is not None else grey.reshape(H, W)).astype(dtype)


def apparent_shift(images: list[np.ndarray], model, shift_px: float, pixels: np.ndarray,
                   h: float = 1e-4, iterations: int = 2) -> list[tuple[float, float]]:
    """The generator's own shift error, without a DIC: for each image, the (su, sv) px that
    make the exact model best fit the image over ``pixels`` (bool (H, W)) in least squares,
    minus the imposed (``shift_px``, 0). ``model(su, sv)`` gives the model's float64 values at
    ``pixels`` for the plate shifted by (su, sv) px (:func:`model_image`). Gauss–Newton from
    the imposed shift with the Jacobian by forward differences (step ``h`` px) there, shared by
    all images. The template is evaluated exactly at any shift, so the estimator has no
    interpolation bias: it returns 0 for the model's own images."""
    m0 = model(shift_px, 0.0)
    J = np.stack([(model(shift_px + h, 0.0) - m0) / h, (model(shift_px, h) - m0) / h], axis=1)
    JtJ = J.T @ J
    out = []
    for img in images:
        y = np.asarray(img, np.float64)[pixels]
        p, m = np.zeros(2), m0
        for it in range(iterations):
            step = np.linalg.solve(JtJ, J.T @ (y - m))
            p += step
            if it + 1 == iterations or np.max(np.abs(step)) < 1e-7:
                break
            m = model(shift_px + p[0], p[1])
        out.append((float(p[0]), float(p[1])))
    return out


# ---- rendering ---------------------------------------------------------------------------------
def render_sequence(renderer: Renderer, seq: dict, n_shifts: int,
                    dtype=np.float32) -> tuple[list[np.ndarray], np.ndarray, list[float]]:
    """The images of one sequence: ([image per shift], reference image, seconds per image).

    The reference is step 0 (undeformed); shift k is step k + 1. ``seq["source"]`` is
    "glsim" (render with its mode, interpolation and spp; float32) or "model"
    (:func:`model_image` in ``dtype``)."""
    scene = renderer.scene
    translations = [(0.0, 0.0, 0.0)] + [tuple(t) for t in scene.specimen.plate.translations]
    images, seconds = [], []
    grid = speckle.dot_grid(renderer.reference.dots) if seq["source"] == "model" else None
    for k in range(n_shifts + 1):
        t0 = time.perf_counter()
        if seq["source"] == "model":
            images.append(model_image(scene, renderer.reference, translations[k], seq["spp"], grid, dtype))
        else:
            res = renderer.render(0, k, mode=seq["mode"], interpolation=seq["interpolation"],
                                  samples_per_pixel=seq["spp"])
            images.append(res.image)
        seconds.append(time.perf_counter() - t0)
    return images[1:], images[0], seconds


def roi_mask(renderer: Renderer, n_steps: int, margin: int = ROI_MARGIN_PX) -> np.ndarray:
    """Pixels whose centre sees the plate at every step, eroded by ``margin`` px."""
    covered = np.ones(renderer.scene.cameras[0].size[::-1], bool)
    for k in range(n_steps):
        res = renderer.render(0, k, truth=True, mode="exact", interpolation="bspline3", samples_per_pixel=1)
        covered &= res.truth.mask
    return ndimage.binary_erosion(covered, iterations=margin) if margin > 0 else covered


def seed_point(roi: np.ndarray) -> list[int]:
    """The ROI pixel nearest the ROI's centroid, [x, y] px."""
    rows, cols = np.nonzero(roi)
    i = np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2)
    return [int(cols[i]), int(rows[i])]


def image_names(seq: dict, n_shifts: int) -> tuple[str, list[str]]:
    """Exchange-folder names: ``<sequence>/reference.tif`` and ``<sequence>/shift_<k>.tif``
    (k = index into the shifts; the zero shift is a separate file: pyvale must not see the
    reference in the deformed list)."""
    return f"{seq['name']}/reference.tif", [f"{seq['name']}/shift_{k:02d}.tif" for k in range(n_shifts)]


def write_exchange(out: str | Path, size=SIZE, shifts_px=SHIFTS_PX, sequences=SEQUENCES,
                   backend: str = "gl", runs=RUNS, seed: int = SEED, apparent: bool = True) -> Path:
    """Render every sequence and write the exchange folder; returns ``manifest.json``'s path.

    Files: ``<sequence>/reference.tif`` and ``<sequence>/shift_<k>.tif`` (16-bit),
    ``roi.tif`` (uint8 0/255), ``scene.json`` and ``manifest.json`` (written last): the shifts
    (px, mm), the scale, per sequence its images, render times, the grey difference of each
    image from the model image of the same shift and (``apparent``) the generator's shift
    error from :func:`apparent_shift`; the ROI, seed, ``calculate_2d`` arguments and the runs.
    """
    out = Path(out)
    shifts_px = [float(s) for s in shifts_px]
    n = len(shifts_px)
    scene = sweep_scene(size, shifts_px, seed)
    scale = mm_per_px(scene.cameras[0])
    mesh = specimen_mesh(scene)
    entries, t_start = [], time.perf_counter()
    with Renderer(scene, backend=backend, mesh=mesh) as r:
        roi = roi_mask(r, n + 1)
        grid = speckle.dot_grid(r.reference.dots)
        models, model_seconds = {}, {}   # spp → (float64 images per shift, reference) of the model
        for spp in sorted({int(s["spp"]) for s in sequences}):
            images, ref, secs = render_sequence(r, {"source": "model", "spp": spp}, n, np.float64)
            models[spp], model_seconds[spp] = (images, ref), secs
        glsim_images = {}
        for seq in sequences:
            if seq["source"] == "model":
                images, ref = models[seq["spp"]]
                seconds = model_seconds[seq["spp"]]
            else:
                # One warm-up render, so that shader compilation is not in the timings.
                r.render(0, 0, mode=seq["mode"], interpolation=seq["interpolation"], samples_per_pixel=seq["spp"])
                images, ref, seconds = render_sequence(r, seq, n)
                glsim_images[seq["name"]] = images
            ref_name, names = image_names(seq, n)
            io.write_image(out / ref_name, ref, BIT_DEPTH)
            for name, img in zip(names, images):
                io.write_image(out / name, img, BIT_DEPTH)
            m_images, m_ref = models[seq["spp"]]
            diff = [np.abs(a.astype(np.float64) - b)[roi] for a, b in zip([ref] + images, [m_ref] + m_images)]
            entries.append({**seq, "reference": ref_name, "deformed": names, "seconds": seconds,
                            "seconds_median": float(np.median(seconds)),
                            "grey_rms_vs_model": [float(np.sqrt(np.mean(d ** 2))) for d in diff[1:]],
                            "grey_max_vs_model": [float(d.max()) for d in diff[1:]]})
        t_apparent = time.perf_counter()
        if apparent:
            fits = {e["name"]: [] for e in entries if e["source"] != "model"}
            fit_pixels = np.zeros_like(roi)      # every APPARENT_STRIDE-th row and column of the ROI
            fit_pixels[::APPARENT_STRIDE, ::APPARENT_STRIDE] = True
            fit_pixels &= roi
            for spp in models:
                names = [e["name"] for e in entries if e["source"] != "model" and e["spp"] == spp]
                if not names:
                    continue

                def model(su, sv, spp=spp):
                    return model_image(scene, r.reference, (su * scale, sv * scale, 0.0), spp, grid,
                                       np.float64, fit_pixels)

                for k, s in enumerate(shifts_px):
                    imgs = [glsim_images[nm][k] for nm in names]
                    for name, p in zip(names, apparent_shift(imgs, model, s, fit_pixels)):
                        fits[name].append(p)
            for e in entries:
                if e["name"] in fits:
                    e["apparent_u"] = [p[0] for p in fits[e["name"]]]
                    e["apparent_v"] = [p[1] for p in fits[e["name"]]]
        t_end = time.perf_counter()
        machine = machine_info(gl_info(r))
    with io.atomic_path(out / "roi.tif") as tmp:
        tifffile.imwrite(tmp, roi.astype(np.uint8) * 255, photometric="minisblack")
    io.write_text(out / "scene.json", scene.to_json())
    manifest = {"format": FORMAT, "size": list(scene.cameras[0].size), "bit_depth": BIT_DEPTH,
                "shifts_px": shifts_px, "shift_mm": [t[0] for t in shifts_mm(shifts_px, scale)],
                "mm_per_px": scale, "direction": "image +x (plate +X)", "sequences": entries,
                "roi": "roi.tif", "roi_pixels": int(roi.sum()), "seed": seed_point(roi),
                "calculate_2d": CALCULATE_2D, "runs": list(runs), "scene": "scene.json",
                "speckle_seed": seed, "backend": backend, "machine": machine,
                "seconds": {"render_and_write": t_apparent - t_start, "apparent_shift": t_end - t_apparent},
                "grey_unit": "full scale (multiply by 255 for 8-bit grey levels)"}
    return io.write_text(out / "manifest.json", json.dumps(manifest, indent=2))


def run_dic(exchange: str | Path, python: str | Path = DIC_PYTHON, script: str | Path = DIC_SCRIPT) -> float:
    """Run ``verify/dic2d.py EXCHANGE`` with the pyvale environment's interpreter, in EXCHANGE;
    returns its wall time (s)."""
    for path, what in ((python, "the pyvale environment's python (make verify / make sweep create .venv-verify)"),
                       (script, "verify/dic2d.py (it lives in the source checkout, not in the wheel)")):
        if not Path(path).exists():
            raise GlsimError(f"{path} not found: {what}; give it with --python / --script")
    exchange = Path(exchange).resolve()
    t0 = time.perf_counter()
    done = subprocess.run([str(Path(python).absolute()), str(Path(script).resolve()), str(exchange)], cwd=exchange)
    if done.returncode != 0:
        raise GlsimError(f"{script} failed with exit status {done.returncode} (its output is above)")
    return time.perf_counter() - t0


# ---- analysis ----------------------------------------------------------------------------------
def shift_stats(u: np.ndarray, v: np.ndarray, ok: np.ndarray, shifts_px) -> list[dict]:
    """Per shift: mean and (population) std over the subsets ``ok`` of u − shift and of v (the
    imposed v is 0), and the largest |u − shift|."""
    rows = []
    for k, s in enumerate(shifts_px):
        du, dv = u[k][ok] - s, v[k][ok]
        rows.append({"shift_px": float(s), "bias_u": float(np.mean(du)), "std_u": float(np.std(du)),
                     "max_abs_u": float(np.max(np.abs(du))), "bias_v": float(np.mean(dv)),
                     "std_v": float(np.std(dv))})
    return rows


def analyse(exchange: str | Path) -> dict:
    """Every sequence × run of an exchange folder whose DIC has run: S-curve rows, and for
    glsim sequences the paired difference to the model sequence (same run, same subsets)."""
    exchange = Path(exchange)
    manifest = json.loads((exchange / "manifest.json").read_text())
    shifts = manifest["shifts_px"]
    seqs = {s["name"]: s for s in manifest["sequences"]}
    out = []
    for run in manifest["runs"]:
        try:   # pyvale's results, each array bounded by its header before it is made
            meas = {name: read_npz(exchange / f"measured_{name}_{run['name']}.npz",
                                   ("ss_x", "ss_y", "u", "v", "valid", "seconds", "pyvale_version")) for name in seqs}
        except (NpzError, OSError) as exc:
            raise GlsimError(f"glsim verify sweep: {exc} — run the DIC again (glsim verify sweep)") from None
        model = next((n for n, s in seqs.items() if s["source"] == "model" and s["spp"] == 1), None)
        for name, seq in seqs.items():
            m = meas[name]
            ok = np.all(m["valid"], axis=0)
            rows = shift_stats(m["u"], m["v"], ok, shifts)
            ref_name = next((n for n, s in seqs.items() if s["source"] == "model" and s["spp"] == seq["spp"]), model)
            if seq["source"] != "model" and ref_name is not None:
                mm = meas[ref_name]
                same = np.array_equal(mm["ss_x"], m["ss_x"]) and np.array_equal(mm["ss_y"], m["ss_y"])
                if same:
                    both = ok & np.all(mm["valid"], axis=0)
                    for k, row in enumerate(rows):
                        d = m["u"][k][both] - mm["u"][k][both]
                        row["gen_u"], row["gen_std_u"] = float(np.mean(d)), float(np.std(d))
            for k, row in enumerate(rows):
                row["grey_rms_vs_model"] = seq["grey_rms_vs_model"][k]
                row["grey_max_vs_model"] = seq["grey_max_vs_model"][k]
                if "apparent_u" in seq:
                    row["apparent_u"], row["apparent_v"] = seq["apparent_u"][k], seq["apparent_v"][k]
            apparent = [r for r in rows if "apparent_u" in r]
            out.append({"sequence": name, "run": run["name"], "subset_size": run["subset_size"],
                        "source": seq["source"], "mode": seq["mode"], "interpolation": seq["interpolation"],
                        "spp": seq["spp"], "n_subsets": int(len(ok)), "n_valid": int(ok.sum()),
                        "dic_seconds": float(m["seconds"]), "pyvale": str(m["pyvale_version"]),
                        "render_seconds": seq["seconds"],
                        "render_seconds_median": seq["seconds_median"],
                        "max_abs_bias_u": max(abs(r["bias_u"]) for r in rows),
                        "max_std_u": max(r["std_u"] for r in rows),
                        "max_abs_bias_v": max(abs(r["bias_v"]) for r in rows),
                        "max_abs_gen_u": max((abs(r["gen_u"]) for r in rows if "gen_u" in r), default=None),
                        "max_abs_apparent_u": max((abs(r["apparent_u"]) for r in apparent), default=None),
                        "max_abs_apparent_v": max((abs(r["apparent_v"]) for r in apparent), default=None),
                        "max_grey_rms_vs_model": max(seq["grey_rms_vs_model"]),
                        "rows": rows})
    keys = ("size", "bit_depth", "shifts_px", "shift_mm", "mm_per_px", "direction", "roi_pixels",
            "calculate_2d", "runs", "speckle_seed", "backend", "machine", "seconds")
    return {"date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            **{k: manifest.get(k) for k in keys}, "results": out}


# ---- plots -------------------------------------------------------------------------------------


# ---- report ------------------------------------------------------------------------------------


# ---- command line ------------------------------------------------------------------------------


STYLE = {"model": ("k", "o", "-"), "exact-procedural": ("tab:green", "s", "--"),
         "exact-bspline3": ("tab:blue", "^", "-"), "q4-bspline3": ("tab:orange", "v", "-."),
         "fast-bspline3": ("tab:red", "D", ":"), "model-spp4": ("0.5", "o", "-"),
         "exact-procedural-spp4": ("tab:olive", "s", "--"), "exact-bspline3-spp4": ("tab:cyan", "^", "-")}


def sequence_style(name: str):
    return STYLE.get(name, ("tab:gray", "P", "-"))


def results_by_sequence(sweep: dict, run: str | None = None) -> dict:
    """sweep results of one run (default the first) by sequence name."""
    run = run or sweep["runs"][0]["name"]
    return {r["sequence"]: r for r in sweep["results"] if r["run"] == run}
