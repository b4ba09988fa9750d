"""Measure detection and calibration accuracy on perfect-target libraries of the Table 8 rig,
without noise and with Table 8's 2 % sensor noise, and write bench/results/calib_accuracy.{json,md}
(the numbers quoted in README.md and docs/calib.md).

    .venv/bin/python examples/calib_accuracy.py [WORK_DIR] [--full-pairs 10] [--more-pairs 30]
                                                [--draws 20]

Renders (or reuses: libraries resume, and examples/calib_detection.py shares them) a 406×308
library of 20 pairs (seed 7, the one tests/test_calib.py uses) and 1624×1234 libraries (seed 1)
without noise and with 2 % noise, then calibrates each with and without the perspective-bias
correction: the noise-free and noisy libraries with --full-pairs pairs, the noisy one also with
--more-pairs pairs (the same library extended; its first pairs are the same poses). For the
noisy calibrations, --draws calibrations of the same views with the *true* centroids plus
Gaussian noise of the measured detection scatter give the spread a calibration of that many
pairs has at that detection noise (median and 90th percentile).
"""
import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from calib_detection import TARGETS, make_library  # noqa: E402

from glsim.backends.gl.context import create_context, info  # noqa: E402

from glsim.bench.report import machine_info, machine_line  # noqa: E402
from glsim.io import images as io  # noqa: E402
from glsim.workflows.calib import calibrate as cal  # noqa: E402
from glsim.workflows.calib import library  # noqa: E402

RESULTS = Path(__file__).resolve().parent.parent / "bench" / "results"
KEYS = ("fx1", "fy1", "cx1", "cy1", "k1_1", "fx2", "fy2", "cx2", "cy2", "k1_2")
MODEL = "k1k2p1p2k3"


def summary(e: dict, truth: dict) -> dict:
    return {**{k + "_rel": e[k] / truth[k] for k in KEYS if not k.startswith("c")},
            **{k + "_px": e[k] for k in KEYS if k.startswith("c")},
            "T_norm_mm": e["T_norm"], "rotation_deg": e["rotation_deg"]}


def spread(lib, dets, pairs, sigma_axis: float, draws: int, min_points: int) -> dict:
    """Calibrations of the detected views with true centroids + N(0, σ²) per axis: the
    median and 90th percentile of max |cx, cy|, |ΔT| and the rotation error."""
    truth = {}
    for p in lib.pairs:
        i = p["pair"]
        if i in pairs:
            truth[i] = tuple(None if dets[i][c] is None else
                             np.where(np.isnan(dets[i][c]), np.nan, library.image_truth(lib, p, cam)["centroid"])
                             for c, cam in enumerate(lib.cameras))
    rng = np.random.default_rng(0)
    rows = []
    for _ in range(draws):
        noisy = {k: tuple(None if v is None else v + rng.normal(0.0, sigma_axis, v.shape) for v in t)
                 for k, t in truth.items()}
        e = cal.errors(cal.calibrate_pairs(lib, noisy, sorted(noisy), MODEL, min_points, 1), *lib.cameras)
        rows.append([max(abs(e[k]) for k in ("cx1", "cy1", "cx2", "cy2")), e["T_norm"], e["rotation_deg"]])
    rows = np.array(rows)
    out = {"draws": draws, "sigma_per_axis_px": sigma_axis}
    for j, name in enumerate(("cxcy_max_px", "T_norm_mm", "rotation_deg")):
        out[name] = {"median": float(np.median(rows[:, j])), "p90": float(np.percentile(rows[:, j], 90))}
    out["fraction_within_goals"] = float(np.mean((rows[:, 0] <= 0.05) & (rows[:, 1] <= 0.005) & (rows[:, 2] <= 0.001)))
    return out


def measure(lib, pairs: int, noise: float, draws: int = 0) -> dict:
    min_points = cal.default_min_points(lib.target)
    chosen = [p["pair"] for p in lib.pairs[:pairs]]
    t0 = time.perf_counter()
    dets = cal.detect_library(lib, min_points)
    dets = {k: v for k, v in dets.items() if k in chosen}
    detect_s = time.perf_counter() - t0
    sub = library.Library(lib.directory, lib.target, lib.cameras, lib.pairs[:pairs], lib.manifest)
    out = {"image_size": list(lib.cameras[0].size), "pairs": pairs, "seed": lib.manifest["seed"],
           "noise_percent": noise, "px_per_mm": lib.target.px_per_mm, "model": MODEL,
           "seconds_per_pair_render": lib.manifest.get("seconds_per_pair"),
           "seconds_per_pair_detect": detect_s / len(lib.pairs), "detection": cal.detection_errors(sub, dets)}
    truth = cal.true_parameters(*lib.cameras)
    for it in (0, 1):
        t0 = time.perf_counter()
        c = cal.calibrate_pairs(lib, dets, chosen, MODEL, min_points, it)
        out[f"bias_iterations_{it}"] = {"pairs_used": len(c.pairs), "rms_px": c.rms, "seconds": time.perf_counter() - t0,
                                        **summary(cal.errors(c, *lib.cameras), truth)}
    if draws:
        sigma = out["detection"]["centroid"]["rms"] / np.sqrt(2)
        out["spread_at_this_detection_noise"] = spread(lib, dets, chosen, sigma, draws, min_points)
    return out


def measure_target(lib, pairs: int, kind: str) -> dict:
    """One row of the target-type table: detection against the projected points (and the true
    centroid for dots), and the calibration's errors (bias-corrected for dots)."""
    mp = cal.default_min_points(lib.target)
    chosen = [p["pair"] for p in lib.pairs[:pairs]]
    dets = {k: v for k, v in cal.detect_library(lib, mp).items() if k in chosen}
    sub = library.Library(lib.directory, lib.target, lib.cameras, lib.pairs[:pairs], lib.manifest)
    c = cal.calibrate_pairs(lib, dets, chosen, MODEL, mp, 1)
    e = cal.errors(c, *lib.cameras)
    truth = cal.true_parameters(*lib.cameras)
    return {"target": kind, "points": len(lib.target.points()), "views_found": sum(d is not None for v in dets.values()
                                                                                    for d in v),
            "views": 2 * pairs, "pairs_used": len(c.pairs), "detection": cal.detection_errors(sub, dets),
            "rms_px": c.rms, "cxcy_max_px": max(abs(e[k]) for k in ("cx1", "cy1", "cx2", "cy2")),
            "fxfy_max_rel": max(abs(e[k] / truth[k]) for k in ("fx1", "fy1", "fx2", "fy2")),
            "k1_max_rel": max(abs(e[k] / truth[k]) for k in ("k1_1", "k1_2")),
            "T_norm_mm": e["T_norm"], "rotation_deg": e["rotation_deg"]}


def target_table(rows: list[dict]) -> list[str]:
    lines = ["## Target types (1624×1234, 10 pairs, seed 1, full field of view)", "",
             "Dots: 9 × 9, 5 mm dots, 10 mm pitch, model-fitted centres, one perspective-bias pass. Chessboard: 9 × 10 "
             "squares of 10 mm (72 inner corners), cv2.findChessboardCornersSB (exhaustive, accuracy). ChArUco: 10 × 9 "
             "squares of 10 mm, 7 mm DICT_5X5_100 markers (72 corners), cv2.aruco.CharucoDetector. Detection error "
             "against the projected point (dots: also against the true centroid, which is what a dot's image "
             "centre is).", "",
             "| target | noise | views found | pairs used | detection vs projected: mean / max (px) | vs centroid: mean / max "
             "| cx, cy max (px) | fx, fy max | k1 max | \\|ΔT\\| (mm) | rotation (°) | RMS (px) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        d = r["detection"]
        cen = f"{d['centroid']['mean']:.4f} / {d['centroid']['max']:.4f}" if "centroid" in d else "–"
        lines.append(f"| {r['target']} | {r['noise_percent']:g} % | {r['views_found']}/{r['views']} | {r['pairs_used']} | "
                     f"{d['projected']['mean']:.4f} / {d['projected']['max']:.4f} | {cen} | {r['cxcy_max_px']:.3f} | "
                     f"{100 * r['fxfy_max_rel']:.4f} % | {100 * r['k1_max_rel']:.3f} % | {r['T_norm_mm']:.4f} | "
                     f"{r['rotation_deg']:.5f} | {r['rms_px']:.4f} |")
    return lines + [""]


def markdown(results: dict) -> str:
    lines = ["# Calibration accuracy (perfect 9×9 target, exact mode, 16 spp, 8-bit, model k1k2p1p2k3)", "",
             f"Machine: {machine_line(results['machine'])}. Written by `{results['command']}`.", ""]
    for name, r in results["runs"].items():
        d = r["detection"]
        lines += [f"## {name}: {r['image_size'][0]}×{r['image_size'][1]}, {r['noise_percent']:g} % noise, "
                  f"{r['pairs']} pairs (seed {r['seed']}, reference {r['px_per_mm']:g} px/mm)", "",
                  f"- render {r['seconds_per_pair_render'] or float('nan'):.2f} s/pair, detection "
                  f"{r['seconds_per_pair_detect']:.2f} s/pair",
                  f"- detection error against the true centroid: mean {d['centroid']['mean']:.4f} px, "
                  f"RMS {d['centroid']['rms']:.4f}, max {d['centroid']['max']:.4f} ({d['centroid']['n']} dots)",
                  f"- against the projected centre: mean {d['projected']['mean']:.4f} px, max {d['projected']['max']:.4f}",
                  "", "| quantity | plain OpenCV | bias-corrected |", "|---|---|---|"]
        a, b = r["bias_iterations_0"], r["bias_iterations_1"]
        for k in a:
            fmt = (lambda v: f"{100 * v:+.4f} %") if k.endswith("_rel") else (lambda v: f"{v:.4g}")
            lines.append(f"| {k} | {fmt(a[k])} | {fmt(b[k])} |")
        s = r.get("spread_at_this_detection_noise")
        if s:
            lines += ["", f"Spread of bias-corrected calibrations of these views at this detection noise ({s['draws']} "
                      f"draws of true centroids + N(0, {s['sigma_per_axis_px']:.4f}² px²) per axis): "
                      f"max |cx, cy| median {s['cxcy_max_px']['median']:.3f} px (90 %: {s['cxcy_max_px']['p90']:.3f}), "
                      f"|ΔT| {s['T_norm_mm']['median']:.4f} mm ({s['T_norm_mm']['p90']:.4f}), rotation "
                      f"{s['rotation_deg']['median']:.5f}° ({s['rotation_deg']['p90']:.5f}); "
                      f"{100 * s['fraction_within_goals']:.0f} % of the draws meet cx, cy ≤ 0.05 px, |ΔT| ≤ 0.005 mm "
                      "and rotation ≤ 0.001° together."]
        lines.append("")
    if results.get("targets"):
        lines += target_table(results["targets"])
    return "\n".join(lines)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work", nargs="?", default="calib-accuracy")
    p.add_argument("--full-pairs", type=int, default=10)
    p.add_argument("--more-pairs", type=int, default=30, help="0: none")
    p.add_argument("--draws", type=int, default=20)
    a = p.parse_args()
    work = Path(a.work)
    ctx = create_context()
    results = {"machine": machine_info(info(ctx)),
               "command": "python examples/calib_accuracy.py " + " ".join(sys.argv[1:]), "runs": {}}
    ci = make_library(work, 0.25, 20, 0.0, ctx=ctx, seed=7)
    results["runs"]["ci"] = measure(ci, 20, 0.0)
    full = make_library(work, 1.0, a.full_pairs, 0.0, ctx=ctx)
    results["runs"]["full"] = measure(full, a.full_pairs, 0.0)
    noisy = make_library(work, 1.0, max(a.full_pairs, a.more_pairs), 2.0, ctx=ctx)
    results["runs"]["full_noise2"] = measure(noisy, a.full_pairs, 2.0, a.draws)
    if a.more_pairs:
        results["runs"][f"full_noise2_{a.more_pairs}pairs"] = measure(noisy, a.more_pairs, 2.0, a.draws)
    results["targets"] = []
    for kind in TARGETS:
        for noise in (0.0, 2.0):
            lib = {(0.0, "dots"): full, (2.0, "dots"): noisy}.get((noise, kind)) or \
                make_library(work, 1.0, a.full_pairs, noise, ctx=ctx, kind=kind)
            results["targets"].append({"noise_percent": noise, **measure_target(lib, a.full_pairs, kind)})
    ctx.release()
    text = markdown(results)
    print(text)
    if a.full_pairs == 10:
        io.write_text(RESULTS / "calib_accuracy.json", json.dumps(results, indent=1))
        io.write_text(RESULTS / "calib_accuracy.md", text)
    else:
        print("(not the documented run: bench/results not written)")


if __name__ == "__main__":
    main()
