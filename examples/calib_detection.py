"""Measure the dot-centre estimators of glsim.workflows.calib.detect on libraries of the Table 8
rig with sensor noise of 0, 1, 2 and 4 % and write bench/results/calib_detection.{json,md}.

    .venv/bin/python examples/calib_detection.py [WORK_DIR] [--pairs 10] [--scale 1.0]
                                                 [--noise 0 1 2 4] [--compare-px-per-mm 10]

Renders (or reuses: libraries resume) one library per noise level (seed 1, perfect 9×9 target,
reference at --px-per-mm auto, exact mode, 16 spp, 8-bit), plus libraries with a coarser
reference (--compare-px-per-mm) at 0 and 2 % noise, then detects every image with every
method and compares each dot's centre with its true centroid (the area centroid of its image).
The Cramér–Rao bound of each dot's centre (the model fit's Fisher information at the image's
noise) is given beside the measurements: no unbiased estimator does better on these images.
Only a run at full size with the default settings writes bench/results.
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np

from glsim.backends.gl.context import create_context, info
from glsim.bench.report import machine_line
from glsim.bench.report import machine_info
from glsim.io import images as io
from glsim.scene import Noise
from glsim.workflows.calib import detect, detection, dotcentres, dotfit, dotgrid, library
from glsim.workflows.calib.dotcentres import METHODS
from glsim.workflows.calib.targets import Charuco, Chessboard, DotGrid

RESULTS = Path(__file__).resolve().parent.parent / "bench" / "results"
NAMES = {"fit": "model fit (default)", "centroid": "grey-level centroid, ±0.45 pitch window (before)",
         "centroid-dot": "grey-level centroid, window = dot + 3 px", "edge-ellipse": "ellipse through sub-pixel edge points",
         "blob": "OpenCV blob centres (findCirclesGrid)"}
SEED = 1


TARGETS = ("dots", "chessboard", "charuco")


def make_target(kind: str, px_per_mm: float):
    """The benchmark targets, of about the same extent (80–100 mm, 72–81 points)."""
    if kind == "dots":
        return DotGrid(px_per_mm=px_per_mm)
    if kind == "chessboard":                       # 8 × 9 inner corners; rows + cols odd: no half-turn symmetry
        return Chessboard(rows=9, cols=10, square=10.0, px_per_mm=px_per_mm)
    return Charuco(squares_x=10, squares_y=9, square=10.0, marker=7.0, px_per_mm=px_per_mm)


def make_library(work: Path, scale: float, pairs: int, noise: float, px_per_mm: float | str = "auto", ctx=None,
                 seed: int = SEED, kind: str = "dots"):
    """The benchmark library for (target kind, scale, noise, reference resolution): rendered or
    resumed (with at least ``pairs`` pairs; measurements take the first ones)."""
    cams = library.paper_rig(scale)
    ppm = library.auto_px_per_mm(cams) if px_per_mm == "auto" else float(px_per_mm)
    prefix = "table8" if kind == "dots" else f"table8_{kind}"
    out = work / f"{prefix}_x{scale:g}_seed{seed}_noise{noise:g}_ppm{ppm:g}"
    if (out / "library.json").is_file():                 # a library is extended, never shrunk
        pairs = max(pairs, json.loads((out / "library.json").read_text())["n_pairs"])
    t0 = time.perf_counter()
    lib = library.write_library(cams, make_target(kind, ppm), pairs, out, seed=seed,
                                noise=Noise(sigma=noise) if noise > 0 else None, ctx=ctx)
    print(f"{out.name}: {len(lib.pairs)} pairs ({time.perf_counter() - t0:.0f} s)", flush=True)
    return lib


def noise_sigma(noise: float, bits: int = 8) -> float:
    """σ of the written image in full-scale grey: the Gaussian noise plus 8-bit quantisation."""
    top = (1 << bits) - 1
    return float(np.sqrt((noise / 100 * (1 << bits) / top) ** 2 + 1 / (12 * top * top)))


def stats(e: np.ndarray) -> dict:
    return {"n": int(len(e)), "mean": float(e.mean()), "rms": float(np.sqrt((e ** 2).mean())), "max": float(e.max())}


def measure(lib, pairs: int, noise: float, methods=METHODS) -> dict:
    markers = np.zeros(lib.target.n_points, bool)
    for r, c in lib.target.markers:
        markers[r * lib.target.cols + c] = True
    errors = {m: [] for m in methods}
    marker_errors = {m: [] for m in methods}
    views = {m: 0 for m in methods}
    seconds = {m: 0.0 for m in methods}
    bound, bound_markers = [], []
    n_views = 0
    for pair in lib.pairs[:pairs]:
        for cam in lib.cameras:
            image = io.read_image(lib.image_path(pair, cam))
            truth = library.image_truth(lib, pair, cam)["centroid"]
            n_views += 1
            for m in methods:
                t0 = time.perf_counter()
                d = detect.detect_dots(image, lib.target, cam.bit_depth, lib.target.n_points // 2 + 1, m)
                seconds[m] += time.perf_counter() - t0
                if d is None:
                    continue
                views[m] += 1
                e = np.linalg.norm(d.points - truth, axis=1)
                ok = ~np.isnan(e)
                errors[m].append(e[ok])
                marker_errors[m].append(e[ok & markers])
            # the Cramér–Rao bound of each dot found by the fit, at this noise level
            img = detection.to_unit(image, cam.bit_depth)
            blobs = dotgrid.find_grid(img, lib.target)
            if blobs is not None and dotgrid.regular(blobs, lib.target.rows, lib.target.cols):
                pts, _, e = dotcentres.refine_fit(img, blobs, lib.target)
                b = dotfit.mean_norm(dotfit.centre_bound(img, e, noise_sigma(noise, cam.bit_depth)))
                ok = np.isfinite(b)
                near = np.linalg.norm(pts[:, None] - truth[None], axis=2)
                is_marker = markers[np.nanargmin(np.where(np.isnan(near), np.inf, near), axis=1)]
                bound.append(b[ok])
                bound_markers.append(b[ok & is_marker])
    out = {"noise_percent": noise, "px_per_mm": lib.target.px_per_mm, "views": n_views,
           "bound": {"mean": float(np.concatenate(bound).mean()),
                     "markers_mean": float(np.concatenate(bound_markers).mean())}, "methods": {}}
    for m in methods:
        e, k = np.concatenate(errors[m]), np.concatenate(marker_errors[m])
        out["methods"][m] = {**stats(e), "markers_mean": float(k.mean()), "markers_max": float(k.max()),
                             "views_found": views[m], "seconds_per_image": seconds[m] / n_views}
    return out


def markdown(results: dict) -> str:
    runs = results["runs"]
    main = [r for r in runs if r["px_per_mm"] == results["px_per_mm"]]
    W, H = results["image_size"]
    lines = [f"# Dot detection against the true centroid ({W}×{H}, Table 8 rig, 9×9 target, {results['pairs']} pairs)",
             "", f"Machine: {machine_line(results['machine'])}. Written by `{results['command']}`.", "",
             f"Every dot found in {2 * results['pairs']} images per noise level (seed {SEED}, perfect target, exact mode, "
             f"16 spp, 8-bit, reference {results['px_per_mm']:g} px/mm); error = |detected − true centroid| (px). "
             "Noise: Gaussian, % of the dynamic range. Cramér–Rao bound: the mean |error| an unbiased estimator "
             "of each dot's centre cannot beat on these images (the model fit's Fisher information).", "",
             "| method | " + " | ".join(f"{r['noise_percent']:g} %: mean / max (markers mean)" for r in main) + " | s/image |",
             "|---|" + "---|" * (len(main) + 1)]
    for m in results["methods"]:
        cells = [f"{r['methods'][m]['mean']:.4f} / {r['methods'][m]['max']:.4f} ({r['methods'][m]['markers_mean']:.4f})"
                 for r in main]
        sec = np.mean([r["methods"][m]["seconds_per_image"] for r in main])
        lines.append(f"| {NAMES[m]} | " + " | ".join(cells) + f" | {sec:.2f} |")
    lines.append("| Cramér–Rao bound | " + " | ".join(
        f"{r['bound']['mean']:.4f} ({r['bound']['markers_mean']:.4f})" if r["noise_percent"] > 0 else "–"
        for r in main) + " | |")
    other = [r for r in runs if r["px_per_mm"] != results["px_per_mm"]]
    if other:
        lines += ["", f"With a coarser target reference ({other[0]['px_per_mm']:g} px/mm, "
                  f"{results['image_px_per_ref_px'][str(other[0]['px_per_mm'])]:.2f} image px per reference px) "
                  "the reference's pixels show in the dot edges:", "",
                  "| method | " + " | ".join(f"{r['noise_percent']:g} %: mean / max" for r in other) + " |",
                  "|---|" + "---|" * len(other)]
        for m in ("fit", "centroid"):
            lines.append(f"| {NAMES[m]} | " + " | ".join(
                f"{r['methods'][m]['mean']:.4f} / {r['methods'][m]['max']:.4f}" for r in other) + " |")
        lines.append("| Cramér–Rao bound | " + " | ".join(
            f"{r['bound']['mean']:.4f}" if r["noise_percent"] > 0 else "–" for r in other) + " |")
    return "\n".join(lines) + "\n"


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work", nargs="?", default="calib-accuracy")
    p.add_argument("--pairs", type=int, default=10)
    p.add_argument("--scale", type=float, default=1.0)
    p.add_argument("--noise", type=float, nargs="+", default=[0, 1, 2, 4])
    p.add_argument("--compare-px-per-mm", type=float, default=10.0, help="0: none")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    a = p.parse_args()
    work = Path(a.work)
    ctx = create_context()
    cams = library.paper_rig(a.scale)
    ppm = library.auto_px_per_mm(cams)
    results = {"machine": machine_info(info(ctx)),
               "command": "python examples/calib_detection.py " + " ".join(__import__("sys").argv[1:]),
               "image_size": list(cams[0].size), "pairs": a.pairs, "seed": SEED, "px_per_mm": ppm,
               "methods": a.methods, "runs": [], "image_px_per_ref_px": {}}
    px_per_mm_image = library.auto_px_per_mm(cams, floor=0) / library.REFERENCE_PX_PER_IMAGE_PX   # ≈ image px per mm
    settings = [(n, ppm) for n in a.noise]
    if a.compare_px_per_mm and a.compare_px_per_mm != ppm:
        settings += [(n, a.compare_px_per_mm) for n in (0.0, 2.0)]
    for noise, px in settings:
        lib = make_library(work, a.scale, a.pairs, noise, px, ctx)
        t0 = time.perf_counter()
        results["runs"].append(measure(lib, a.pairs, noise, a.methods))
        results["image_px_per_ref_px"][str(px)] = px_per_mm_image / px
        print(f"  measured in {time.perf_counter() - t0:.0f} s", flush=True)
    ctx.release()
    text = markdown(results)
    print(text)
    if a.scale == 1.0 and a.pairs == 10 and a.methods == list(METHODS):
        io.write_text(RESULTS / "calib_detection.json", json.dumps(results, indent=1))
        io.write_text(RESULTS / "calib_detection.md", text)
    else:
        print("(a reduced run: bench/results not written)")


if __name__ == "__main__":
    main()
