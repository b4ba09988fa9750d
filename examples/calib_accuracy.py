"""Measure detection and calibration accuracy on perfect-target libraries of the Table 8 rig
and write bench/results/calib_accuracy.{json,md} (the numbers quoted in docs/calib.md).

    .venv/bin/python examples/calib_accuracy.py [WORK_DIR] [--full-pairs 10]

Renders (or reuses, libraries resume) a 406×308 library of 20 pairs (seed 7, the one
tests/test_calib.py uses) and a 1624×1234 library of --full-pairs pairs (seed 1), then
calibrates each with and without the perspective-bias correction.
"""
import argparse
import json
import os
import platform
import time
from pathlib import Path

from glsim.io import images as io
from glsim.workflows.calib import calibrate as cal
from glsim.workflows.calib import library
from glsim.workflows.calib.targets import DotGrid

RESULTS = Path(__file__).resolve().parent.parent / "bench" / "results"
KEYS = ("fx1", "fy1", "cx1", "cy1", "k1_1", "fx2", "fy2", "cx2", "cy2", "k1_2")


def measure(directory: Path, scale: float, pairs: int, seed: int) -> dict:
    t0 = time.perf_counter()
    lib = library.write_library(library.paper_rig(scale), DotGrid(), pairs, directory, seed=seed)
    render_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    dets = cal.detect_library(lib, 41)
    detect_s = time.perf_counter() - t0
    out = {"image_size": list(lib.cameras[0].size), "pairs": pairs, "seed": seed,
           "seconds_per_pair_render": lib.manifest.get("seconds_per_pair", render_s / pairs),
           "seconds_per_pair_detect": detect_s / pairs, "detection": cal.detection_errors(lib, dets)}
    truth = cal.true_parameters(*lib.cameras)
    for it in (0, 1):
        t0 = time.perf_counter()
        c = cal.calibrate_pairs(lib, dets, [p["pair"] for p in lib.pairs], "k1k2p1p2k3", 41, it)
        e = cal.errors(c, *lib.cameras)
        out[f"bias_iterations_{it}"] = {
            "pairs_used": len(c.pairs), "rms_px": c.rms, "seconds": time.perf_counter() - t0,
            **{k + "_rel": e[k] / truth[k] for k in KEYS if not k.startswith("c")},
            **{k + "_px": e[k] for k in KEYS if k.startswith("c")},
            "T_norm_mm": e["T_norm"], "rotation_deg": e["rotation_deg"]}
    return out


def markdown(results: dict) -> str:
    lines = ["# Calibration accuracy (perfect 9×9 target, no noise, exact mode, 16 spp, 8-bit)", "",
             f"Machine: {results['machine']}. Written by examples/calib_accuracy.py.", ""]
    for name, r in results["runs"].items():
        d = r["detection"]
        lines += [f"## {name}: {r['image_size'][0]}×{r['image_size'][1]}, {r['pairs']} pairs (seed {r['seed']})", "",
                  f"- render {r['seconds_per_pair_render']:.2f} s/pair, detection {r['seconds_per_pair_detect']:.2f} s/pair",
                  f"- detection error against the true centroid: mean {d['centroid']['mean']:.4f} px, "
                  f"RMS {d['centroid']['rms']:.4f}, max {d['centroid']['max']:.4f} ({d['centroid']['n']} dots)",
                  f"- against the projected centre: mean {d['projected']['mean']:.4f} px, max {d['projected']['max']:.4f}",
                  "", "| quantity | plain OpenCV | bias-corrected |", "|---|---|---|"]
        a, b = r["bias_iterations_0"], r["bias_iterations_1"]
        for k in a:
            fmt = (lambda v: f"{100 * v:+.4f} %") if k.endswith("_rel") else (lambda v: f"{v:.4g}")
            lines.append(f"| {k} | {fmt(a[k])} | {fmt(b[k])} |")
        lines.append("")
    return "\n".join(lines)


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("work", nargs="?", default="calib-accuracy")
    p.add_argument("--full-pairs", type=int, default=10)
    a = p.parse_args()
    work = Path(a.work)
    results = {"machine": f"{os.cpu_count()} CPUs ({platform.machine()}), GL on EGL", "runs": {
        "ci": measure(work / "ci", 0.25, 20, 7),
        "full": measure(work / "full", 1.0, a.full_pairs, 1)}}
    io.write_text(RESULTS / "calib_accuracy.json", json.dumps(results, indent=1))
    io.write_text(RESULTS / "calib_accuracy.md", markdown(results))
    print(markdown(results))


if __name__ == "__main__":
    main()
