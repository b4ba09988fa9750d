"""``glsim calib …``: calibration libraries, calibrations and Monte-Carlo studies.

    glsim calib library SCENE.toml|default --pairs N -o DIR [--max-pairs M] [--min-points N] [--scale S]
                        [--seed K] [--fov full|centre]
                        [--target dots|chessboard|charuco] [--rows 9 --cols 9 --pitch 10 --dot 5 --marker 7]
                        [--sigma MM] [--pitch-error E] [--target-seed K] [--px-per-mm auto] [--noise 2]
                        [--blur] [--lighting] [--spp 16] [--backend gl|cpu] [--workers N] [--scheduler ADDR]
    glsim calib run DIR [-o OUT] [--model k1k2p1p2k3] [--min-points N] [--bias-iterations 1] [-j PROCS]
    glsim calib study {images,fov,quality} LIB [LIB …] -o OUT [--sizes 10 25 50] [--runs 100]
                      [--seed K] [--model …] [--bias-iterations 1] [-j PROCS]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

from glsim.errors import GlsimError, SceneError
from glsim.scene import Noise, Render, Scene, load_scene
from glsim.workflows.calib import calibrate as cal
from glsim.workflows.calib import library as libmod
from glsim.workflows.calib import study as studymod
from glsim.workflows.calib.poses import FOVS, PoseSpec
from glsim.workflows.calib.targets import Charuco, Chessboard, Defects, DotGrid


def _progress(what: str):
    t0 = time.perf_counter()

    def report(done: int, total: int) -> None:
        eta = (time.perf_counter() - t0) / done * (total - done)
        print(f"\r{what} {done}/{total}  ({eta:.0f} s left)", end="" if done < total else "\n",
              file=sys.stderr, flush=True)
    return report


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="glsim calib", description="Calibration-target libraries and studies")
    sub = p.add_subparsers(dest="command", required=True)

    lib = sub.add_parser("library", help="render a library of stereo pairs of a calibration target")
    lib.add_argument("scene", help="a scene TOML (its cameras and [render] options, with --spp), or "
                                   "'default' for the paper's Table 8 rig (exact mode)")
    lib.add_argument("--pairs", type=int, required=True,
                     help="stereo pairs `calib run` can use (both cameras see enough dots): pairs are drawn "
                          "until there are this many")
    lib.add_argument("--max-pairs", type=int, default=None,
                     help="pairs drawn at most before giving up (default 4 × --pairs)")
    lib.add_argument("--min-points", type=int, default=None,
                     help="dots both views of a usable pair detect (default: half; as for calib run)")
    lib.add_argument("-o", "--output", required=True, help="library directory")
    lib.add_argument("--scale", type=float, default=1.0, help="image size factor for 'default' (0.25: 406×308)")
    lib.add_argument("--seed", type=int, default=0)
    lib.add_argument("--fov", choices=FOVS, default="full", help="target positions over the full FOV or centre")
    lib.add_argument("--sigma", type=float, default=0.0, help="random dot-centre scatter of the target, mm")
    lib.add_argument("--pitch-error", type=float, default=0.0, help="relative pitch error of the target")
    lib.add_argument("--target-seed", type=int, default=0, help="seed of the target's defects")
    lib.add_argument("--target", choices=("dots", "chessboard", "charuco"), default="dots",
                     help="dot grid (default), chessboard or OpenCV ChArUco board")
    lib.add_argument("--rows", type=int, default=None, help="dot rows, or rows of squares (default 9 / 7 / 5)")
    lib.add_argument("--cols", type=int, default=None, help="dot columns, or columns of squares (default 9 / 10 / 7)")
    lib.add_argument("--pitch", type=float, default=10.0, help="dot pitch or square size, mm")
    lib.add_argument("--dot", type=float, default=5.0, help="dot diameter, mm")
    lib.add_argument("--marker", type=float, default=None, help="ChArUco marker size, mm (default 0.7 × pitch)")
    lib.add_argument("--spp", type=int, default=16, help="samples per pixel (16 makes dot centroids exact to "
                                                          "the pixel-sampling limit; 4 gives 0.02 px errors)")
    lib.add_argument("--backend", choices=("gl", "cpu"), default=None)
    lib.add_argument("--noise", type=float, default=2.0,
                     help="Gaussian sensor noise, %% of the dynamic range (Table 8: 2; 0 = none); "
                          "a scene's own [noise] table takes precedence")
    lib.add_argument("--px-per-mm", default="auto",
                     help="resolution of the target's reference image; 'auto': ≥ 4 reference px per image px "
                          "(35 for the full-size Table 8 rig, 10 at --scale 0.25), so that the reference's pixels "
                          "do not show in the dots' edges")
    lib.add_argument("--blur", action="store_true", help="apply the scene's [optics] depth of field to every image")
    lib.add_argument("--lighting", action="store_true", help="apply the scene's [lighting] to every image")
    lib.add_argument("--workers", type=int, default=1, help="worker processes rendering pairs (the image library's "
                     "engine: `glsim library --workers`); the same files whatever the number")
    lib.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                     help="render the pairs on this Dask cluster instead (as `glsim library --scheduler`)")

    run = sub.add_parser("run", help="detect, calibrate and report a library")
    run.add_argument("library", help="library directory")
    run.add_argument("-o", "--output", default=None, help="output directory (default LIBRARY/calibration)")
    run.add_argument("--model", choices=list(cal.MODELS), default="k1k2p1p2k3", help="distortion terms fitted")
    run.add_argument("--min-points", type=int, default=None, help="dots a view needs (default: half)")
    run.add_argument("--bias-iterations", type=int, default=1,
                     help="perspective-bias corrections of the dot centroids (0: plain OpenCV)")
    run.add_argument("-j", "--processes", type=int, default=1)

    st = sub.add_parser("study", help="Monte-Carlo calibrations on random balanced subsets")
    st.add_argument("study", choices=studymod.STUDIES)
    st.add_argument("libraries", nargs="+", help="library directories (fov: full and centre; quality: one per σ)")
    st.add_argument("-o", "--output", required=True, help="study directory (study.csv, figures, summary.md)")
    st.add_argument("--sizes", type=int, nargs="+", default=None, help="pairs per calibration (default Table 6)")
    st.add_argument("--runs", type=int, nargs="+", default=None, help="calibrations per size (one, or one each)")
    st.add_argument("--seed", type=int, default=0)
    st.add_argument("--model", choices=list(cal.MODELS), default="k1k2p1p2k3")
    st.add_argument("--min-points", type=int, default=None)
    st.add_argument("--bias-iterations", type=int, default=1)
    st.add_argument("-j", "--processes", type=int, default=1)
    return p


def _target(a, ppm: float):
    """The target `calib library` draws (``ppm``: reference px per mm)."""
    if a.target == "dots":
        return DotGrid(rows=a.rows or 9, cols=a.cols or 9, pitch=a.pitch, dot_diameter=a.dot, px_per_mm=ppm,
                       defects=Defects(sigma=a.sigma, pitch_error=a.pitch_error, seed=a.target_seed))
    for flag, value in (("--sigma", a.sigma), ("--pitch-error", a.pitch_error), ("--target-seed", a.target_seed)):
        if value:
            raise SceneError(flag, f"applies to dot grids, not to a {a.target}", f"leave {flag} out, or use --target dots")
    if a.target == "chessboard":
        return Chessboard(rows=a.rows or 7, cols=a.cols or 10, square=a.pitch, px_per_mm=ppm)
    ppm = math.ceil(ppm * a.pitch - 1e-9) / a.pitch          # whole reference pixels per square
    return Charuco(squares_x=a.cols or 7, squares_y=a.rows or 5, square=a.pitch,
                   marker=a.marker or 0.7 * a.pitch, px_per_mm=ppm)


def _library(a) -> int:
    if a.workers < 1:
        raise SceneError("--workers", f"must be ≥ 1, got {a.workers}", "give the number of worker processes")
    if not a.noise >= 0:
        raise SceneError("--noise", f"must be ≥ 0 (percent of the dynamic range), got {a.noise:g}",
                         "give 0 for noise-free images, or e.g. 2 (Table 8)")
    if a.scene == "default":
        rig = Scene(cameras=libmod.paper_rig(a.scale), render=Render(mode="exact", samples_per_pixel=a.spp))
    else:
        rig = load_scene(a.scene).replace(render={"samples_per_pixel": a.spp})
    spec = PoseSpec(fov=a.fov)
    if a.px_per_mm == "auto":
        ppm = libmod.auto_px_per_mm(rig.cameras, spec)
    else:
        try:
            ppm = float(a.px_per_mm)
        except ValueError:
            raise SceneError("--px-per-mm", f"{a.px_per_mm!r} is not a number", "give px per mm, or auto") from None
    target = _target(a, ppm)
    noise = rig.noise or (Noise(sigma=a.noise) if a.noise > 0 else None)
    effects = tuple(e for e, on in (("blur", a.blur), ("lighting", a.lighting)) if on)
    lib, good = cal.write_usable_library(rig, target, a.pairs, a.output, a.max_pairs, a.min_points,
                                         progress=_progress("pairs"), seed=a.seed, backend=a.backend,
                                         spec=spec, noise=noise, effects=effects, workers=a.workers,
                                         scheduler=a.scheduler)
    complete = sum(all(c["complete"] for c in p["cameras"].values()) for p in lib.pairs)
    print(f"{len(lib.pairs)} pairs drawn in {a.output}: {len(good)} usable by `glsim calib run` "
          f"({a.pairs} asked for; {complete} wholly in view in every camera)")
    return 0


# Units of the calibration parameters (report.json names): px, mm, deg; distortion is unitless.
UNITS = {"fx": "px", "fy": "px", "cx": "px", "cy": "px", "Tx": "mm", "Ty": "mm", "Tz": "mm",
         "Theta": "deg", "Phi": "deg", "Psi": "deg"}
ROWS = (("fx1", "fy1", "cx1", "cy1"), ("k1_1", "k2_1", "p1_1", "p2_1", "k3_1"),
        ("fx2", "fy2", "cx2", "cy2"), ("k1_2", "k2_2", "p1_2", "p2_2", "k3_2"),
        ("Tx", "Ty", "Tz"), ("Theta", "Phi", "Psi"))


def unit(name: str) -> str:
    """The unit of a calibration parameter ("" for the distortion coefficients)."""
    return UNITS.get(name.rstrip("0123456789") if name[:1] in "fc" else name, "")


def error_lines(errors: dict[str, float]) -> list[str]:
    """Every parameter's error (estimate − truth) with its unit, the largest of each unit marked
    with ◀, and a last line naming those largest errors."""
    rows = [row for row in ROWS if any(n in errors for n in row)]
    rest = tuple(n for n in errors if n not in {m for row in ROWS for m in row} | {"T_norm", "rotation_deg"})
    rows += [rest] if rest else []          # parameters under other names are printed too
    names = [n for row in rows for n in row if n in errors]
    worst = {}
    for n in names:
        u = unit(n)
        if u not in worst or abs(errors[n]) > abs(errors[worst[u]]):
            worst[u] = n
    marked = set(worst.values())

    def item(n: str) -> str:
        u = unit(n)
        return f"{n} {errors[n]:+.4g}{' ' + u if u else ''}{' ◀' if n in marked else ''}"

    lines = ["errors (estimate − truth; ◀ the largest of its unit):"]
    for row in rows:
        shown = [item(n) for n in row if n in errors]
        if shown:
            tail = "  (distortion, unitless)" if all(not unit(n) for n in row) else ""
            lines.append("  " + ",  ".join(shown) + tail)
    extra = [f"|T error| {errors['T_norm']:.4g} mm" if "T_norm" in errors else "",
             f"rotation error {errors['rotation_deg']:.4g} deg" if "rotation_deg" in errors else ""]
    if any(extra):
        lines.append("  " + ",  ".join(x for x in extra if x))
    order = ("px", "mm", "deg", "")
    lines.append("largest: " + ", ".join(
        f"{worst[u]} {errors[worst[u]]:+.4g}{' ' + u if u else ' (distortion)'}" for u in order if u in worst))
    return lines


def _run(a) -> int:
    rep = cal.run(a.library, a.output, a.model, a.min_points, a.bias_iterations, a.processes, _progress("detect"))
    print(f"{rep['pairs_used']}/{rep['pairs']} pairs used, RMS {rep['rms']:.4f} px, "
          f"max epipolar distance {rep['epipolar_max_px']:.4f} px")
    if rep.get("views_skipped"):
        counts: dict[str, int] = {}
        for v in rep["views_skipped"]:
            counts[v["reason"]] = counts.get(v["reason"], 0) + 1
        print(f"{len(rep['views_skipped'])} views skipped (per view in residuals.csv):")
        for reason, n in sorted(counts.items(), key=lambda x: -x[1]):
            print(f"  {n} × {reason}")
    print("\n".join(error_lines(rep["errors"])))
    det = rep["detection"]
    if "centroid" in det:
        print(f"detection: mean |error| {det['centroid']['mean']:.4f} px against the true centroid, "
              f"{det['projected']['mean']:.4f} px against the projected centre")
    else:
        print(f"detection: mean |error| {det['projected']['mean']:.4f} px against the projected corners")
    return 0


def _study(a) -> int:
    out = Path(a.output)
    rows = studymod.run_study(a.study, a.libraries, out / "study.csv", a.sizes, a.runs, a.seed, a.model,
                              a.min_points, a.bias_iterations, a.processes, _progress("calibrations"))
    figs = studymod.figures(a.study, rows, out)
    studymod.write_summary(out / "summary.md", rows)
    print(f"{len(rows)} calibrations in {out / 'study.csv'}; figures: {', '.join(f.name for f in figs)}")
    return 0


def main(argv=None) -> int:
    """Entry point of ``glsim calib``; returns the exit status (2 for bad input)."""
    a = parser().parse_args(argv)
    try:
        return {"library": _library, "run": _run, "study": _study}[a.command](a)
    except GlsimError as exc:
        print(f"glsim calib: {exc}", file=sys.stderr)
        return 2
