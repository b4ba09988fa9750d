"""glsim design SPEC.toml -o DIR: what will my DIC measure? Candidate set-ups and DIC settings in,
predicted and measured error maps and a ranking out (docs/design.md).

Writes, all under DIR: ``rows/<key>/`` (one cached row each: ``result.npz``, ``row.json``), ``rows.csv``
(one line per row), ``ranking.csv`` (one line per set-up × DIC setting, best first), ``results.json``
(all of it) and ``report.html`` (self-contained: figures inline). Run again to resume.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.workflows.design import report as rep
from glsim.workflows.design.engine import engine as make_engine
from glsim.workflows.design.planar import setup_scene
from glsim.workflows.design.run import FORMAT, calibration_report, print_progress, run
from glsim.workflows.design.spec import criteria_for, load_design

NOTES = (
    "Quick mode: the Cramér–Rao bound σ²(JᵀJ)⁻¹ of a subset DIC with the shape function, J the subset's "
    "pixels × its parameters from the noise-free image's B-spline gradient; both images noisy (×2 in variance); "
    "σ per pixel from the scene's noise model plus quantisation. It is a lower bound on the noise, with no bias.",
    "Bias map: mean over realisations of measured − truth at each subset centre; noise map: their std "
    "(ddof = 1); both need the engine. Noise floor: std of the static pair's measured U, V (truth 0).",
    "mm: px times the camera scale Z/√(fx·fy) at each subset centre (in-plane, as seen by this camera).",
    "Spatial resolution ([resolution]): a flat plate square onto the camera at the specimen's depth, moved by "
    "u(x) = A·sin(2πx/p) through its FE nodes (32 per smallest period); the measured U fitted by a sinusoid of "
    "the known period per period; the resolution is the period at 90 % of the imposed amplitude; the "
    "metrological efficiency indicator (MEI) is noise floor × spatial resolution (px²).",
    "Strain ([dic] strain_window): pyvale.strain.calculate_2d (pyvale2d) or calculate_3d (pyvale3d: the surface "
    "strain in pyvale's tangent basis, camera 0's x projected onto the surface) on the measured displacements "
    "(invalid subsets left out), in the formulation asked for; the truth the same measure of F = I + ∇u of the "
    "exact field at each strain point. Strain bias, noise and noise floor as for the displacements; criteria "
    "pooled over exx, eyy, exy (tensor shear), in strain (not %, not µε).",
    "Not modelled here: calibration error only with [calibration] rig = \"targets\" (stereo).",
)
STEREO_NOTES = (
    "Stereo (engine pyvale3d): subsets on camera 0's reference image; X, Y, Z (the reference state's shape) "
    "and U, V, W (the deformed state's displacement) in mm, camera 0's frame, against the exact truth of the "
    "material point seen at each subset centre. Bias map: mean over realisations − truth; noise map: their std "
    "(ddof = 1). Noise floor: std of the static pair's U, V, W (truth 0), and of its X, Y, Z minus the "
    "reference state's over √2. The quick mode stays 2-D, on camera 0 (px); the spatial resolution is that of an "
    "out-of-plane sinusoid W along the normal of a plate facing the stereo bisector (mei_W_mm2: W noise floor × "
    "resolution in mm). "
    "Maps are drawn on camera 0's reference image, the ROI (the specimen both cameras see) outlined.",
)


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="glsim design", description=__doc__.split("\n\n")[0])
    ap.add_argument("spec", help="design spec (TOML; docs/design.md)")
    ap.add_argument("-o", "--output", required=True, help="output folder (resumed when run again)")
    ap.add_argument("--quick", action="store_true", help="quick mode only, whatever the spec's engine")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    return ap


def _check_output(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise GlsimError(f"-o {out}: is a file, not a folder — give a folder for the design's results")
    if out.is_symlink():
        raise GlsimError(f"-o {out}: is a symbolic link — give a real folder")


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    try:
        design = load_design(args.spec)
        out = Path(args.output)
        _check_output(out)
        eng = None
        if design.engine != "quick" and not args.quick:
            eng = make_engine(design.engine)
            why = eng.missing()
            if why:
                print(f"glsim design: warning: engine {design.engine} cannot run: {why}. Running the quick mode only.",
                      file=sys.stderr)
                eng = None
        by = design.rank_by if eng is not None or not criteria_for(design.engine)[design.rank_by][1] \
            else "quick_sigma_px"
        t0 = time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        results = run(design, out, eng, None if args.quiet else print_progress)
        entries = rep.aggregate(design, results)
        ranking = rep.rank(entries, by)
        row_table = [rep.row_summary(r) for r in results]
        image_shape = design.plan.variants[0].scene.camera(design.camera).size[::-1]
        notes = NOTES + (STEREO_NOTES if design.stereo and eng is not None else ())
        calibration = {"rig": design.rig}
        if design.stereo and eng is not None and design.rig != "exact":
            calibration["setups"] = {v.id: calibration_report(design, setup_scene(v.scene, design.speckle_seeds[0]), out)
                                     for v in design.plan.variants}
        meta = {"spec": str(args.spec), "notes": notes, "calibration": calibration}
        rep.write_csv(out / "rows.csv", row_table)
        rep.write_csv(out / "ranking.csv", ranking)
        design_used = design if by == design.rank_by else _with_rank(design, by)
        io.write_text(out / "report.html", rep.html_report(design_used, ranking, entries, image_shape, meta))
        seconds = time.perf_counter() - t0
        io.write_text(out / "results.json", json.dumps(rep.clean(
            {"format": FORMAT, "spec": str(args.spec), "engine": eng.name if eng else "quick", "rank_by": by,
             "camera": design.camera, "cameras": list(design.cameras) or [design.camera], "step": design.step, "noise_seeds": list(design.noise_seeds),
             "speckle_seeds": list(design.speckle_seeds), "calibration": calibration, "ranking": ranking,
             "rows": row_table, "notes": list(notes), "seconds": seconds}), indent=2, allow_nan=False) + "\n")
    except GlsimError as exc:
        print(f"glsim design: error: {exc}", file=sys.stderr)
        return 2
    best = ranking[0]
    print(f"glsim design: {len(results)} rows ({len(entries)} set-up × setting pairs) in {seconds:.1f} s; best by "
          f"{by}: {best['setup']} {best['setting']} ({by} = {best.get(by, float('nan')):.3g})")
    print(f"glsim design: wrote {out}/report.html, results.json, ranking.csv and rows.csv")
    return 0


def _with_rank(design, by: str):
    import dataclasses
    return dataclasses.replace(design, rank_by=by)
