"""Figures in README.md and docs/ generated from the results files (``glsim docs [--check]``).

A generated region is delimited in the markdown by

    <!-- generated: NAME from SOURCE[, SOURCE…] -->
    …
    <!-- end generated -->

and its body is what ``GENERATORS[NAME]`` makes of the named results files (paths relative to
the repository). ``glsim docs`` rewrites every region; ``glsim docs --check`` (``make
readme-check``, part of ``make test``) fails naming each region whose text differs. Timing
figures come first as ratios measured in one run, then absolute times with the machine, which
vary from machine to machine.
"""
from __future__ import annotations

import csv
import difflib
import json
import re
from pathlib import Path

from glsim.errors import GlsimError
from glsim.evaluation.report import machine_line
from glsim.io import images as io

FILES = ("README.md", "docs/calib.md", "docs/verify.md", "docs/library.md", "docs/preview.md", "docs/effects.md",
         "docs/scaling.md", "docs/scene.md", "docs/fe_bulge.md", "docs/hard_cases.md", "docs/rig_files.md",
         "docs/quadratic.md")
REGION = re.compile(r"(<!-- generated: (?P<name>[\w-]+) from (?P<sources>[^>]+?) -->\n)(?P<body>.*?)(<!-- end generated -->)",
                    re.S)


# ---- formatting ------------------------------------------------------------------------------
def _s(x: float | None, digits: int = 2) -> str:
    """``x`` to ``digits`` significant digits, plainly for 1e-3 ≤ |x| < 1e4, else as 1.2e-05 → 1.2e-5."""
    if x is None:
        return "–"
    if x == 0:
        return "0"
    if 1e-3 <= abs(x) < 1e4:
        return f"{x:#.{digits}g}".rstrip(".")
    m, e = f"{x:.{digits - 1}e}".split("e")
    return f"{m}e{int(e)}"


def _ratio(a: float, b: float) -> str:
    return f"{a / b:.2g}×" if a / b < 10 else f"{a / b:.0f}×"




# ---- accuracy.json ---------------------------------------------------------------------------
EXCERPT = (("gl", "fast", "linear", 1, "fp64"), ("gl", "fast", "bspline3", 1, "fp64"),
           ("gl", "q4", "bspline3", 1, "fp64"), ("gl", "exact", "bspline3", 1, "fp64"),
           ("gl", "exact", "bspline3", 4, "fp64"), ("gl", "exact", "bspline3", 4, "fp64", "newton"),
           ("gl", "exact", "bspline3", 1, "fp32"),
           ("gl", "exact", "procedural", 1, "fp64"), ("gl", "exact", "procedural", 4, "fp64"),
           ("cpu", "exact", "bspline3", 1, "fp64"))


def _record(acc: dict, backend: str, mode: str, interp: str, spp: int, precision: str = "fp64",
            subsamples: str = "mapped") -> dict:
    for r in acc["records"]:
        if (r["backend"], r["mode"], r["interpolation"], r["spp"], r["precision"], r.get("subsamples", "mapped")) \
                == (backend, mode, interp, spp, precision, subsamples):
            return r
    raise GlsimError(f"accuracy.json has no row {backend} {mode} {interp} {spp} spp {precision} {subsamples}: "
                     "run `glsim bench accuracy` at full size")


def accuracy_table(acc: dict) -> str:
    base = _record(acc, "gl", "exact", "bspline3", 1)
    lines = [f"Bulge, camera 0 at the full bulge, {acc['size'][0]}×{acc['size'][1]}; time relative to GL exact "
             f"fp64 bspline3 at 1 spp in the same run, then the median per image on {machine_line(acc['machine'])} "
             f"({acc['date'][:10]}); mapping error in reference-image px against the float64 exact oracle; grey "
             "error in 8-bit grey levels against the exact speckle.", "",
             "| backend | mode | arithmetic | interpolation | spp | time ratio | time (s) | mapping RMS / max (px) "
             "| grey RMS vs exact speckle |", "|---|---|---|---|---|---|---|---|---|"]
    for key in EXCERPT:
        r = _record(acc, *key)
        mode = ("exact (oracle)" if r["backend"] == "cpu" else "q4 (paper)" if r["mode"] == "q4"
                else "exact, newton sub-samples" if r.get("subsamples") == "newton" else r["mode"])
        mapping = "0" if r["map_max_px"] == 0 else f"{_s(r['map_rms_px'])} / {_s(r['map_max_px'])}"
        lines.append(f"| {r['backend']} | {mode} | {r['arithmetic']} | {r['interpolation']} | {r['spp']} | "
                     f"{_ratio(r['seconds'], base['seconds'])} | {_s(r['seconds'])} | {mapping} | "
                     f"{_s(r['speckle_rms'])} |")
    return "\n".join(lines)


def accuracy_facts(acc: dict) -> str:
    ex, ex32 = _record(acc, "gl", "exact", "bspline3", 1), _record(acc, "gl", "exact", "bspline3", 1, "fp32")
    gl = [r for r in acc["records"] if r["backend"] == "gl" and r["precision"] == "fp64"]
    approx = [r for r in gl if r["mode"] in ("fast", "q4")]
    grey1 = [r["speckle_rms"] for r in gl if r["spp"] == 1 and r["interpolation"] != "procedural"]
    cpu = {(r["mode"], r["interpolation"]): r["seconds"] for r in acc["records"] if r["backend"] == "cpu" and r["spp"] == 1}
    speedups = [cpu[m, i] / _record(acc, "gl", m, i, 1)["seconds"] for m, i in cpu]
    fast = {r["interpolation"]: r["seconds"] / ex["seconds"] for r in gl if r["mode"] == "fast" and r["spp"] == 1}
    q4 = _record(acc, "gl", "q4", "bspline3", 1)
    return "\n".join([
        f"- GL `exact` (fp64) maps every pixel within {_s(max(r['map_max_px'] for r in gl if r['mode'] == 'exact'))} px "
        "of the float64 oracle; its fp32 variant errs by up to "
        f"{_s(ex32['map_max_px'])} px and takes {_ratio(ex32['seconds'], ex['seconds'])} the fp64 time.",
        f"- `fast` and the paper's `q4` misplace the speckle by up to {_s(max(r['map_max_px'] for r in approx))} px "
        f"(RMS {_s(min(r['map_rms_px'] for r in approx))}–{_s(max(r['map_rms_px'] for r in approx))} px); at 1 spp "
        f"`q4` takes {_ratio(q4['seconds'], ex['seconds'])} and `fast` "
        f"{_ratio(min(fast.values()), 1)}–{_ratio(max(fast.values()), 1)} the time of `exact`.",
        f"- Texture interpolation of the generated speckle leaves {_s(min(grey1))}–{_s(max(grey1))} grey levels RMS "
        "at 1 spp; the procedural speckle "
        f"{_s(_record(acc, 'gl', 'exact', 'procedural', 1)['speckle_rms'])}.",
        f"- The GL path is {_ratio(min(speedups), 1)}–{_ratio(max(speedups), 1)} faster than the numpy oracle at 1 spp "
        "(same modes and interpolations).",
        *[f"- At {spp} spp (bspline3), sub-samples placed by Newton from the pixel centre (`subsamples = \"newton\"`) take "
          f"{_ratio(nw['seconds'], mp['seconds'])} the time of sub-samples each mapped on its ray; grey error against the "
          f"oracle's image: max {_s(nw['grey_max'])} grey levels (mapped: {_s(mp['grey_max'])})."
          for spp in sorted({r["spp"] for r in gl if r.get("subsamples") == "newton"})
          for nw, mp in [(_record(acc, "gl", "exact", "bspline3", spp, "fp64", "newton"),
                          _record(acc, "gl", "exact", "bspline3", spp))]],
    ])


def peer(acc: dict) -> str:
    p = {x["name"].split()[0] if x["name"].startswith("riley") else x["name"]: x for x in acc["peer"]}
    riley, q4, ex = p.get("riley-raster"), p.get("glsim GL q4 fp64"), p.get("glsim GL exact fp64")
    if not (riley and q4 and ex) or "ok" != riley["status"]:
        return "riley-raster was not installed in the run that wrote accuracy.json."
    name = next(x["name"] for x in acc["peer"] if x["name"].startswith("riley"))
    return (f"Peer, same run, interleaved ({machine_line(acc['machine'])}): glsim GL takes "
            f"{_ratio(q4['seconds'], riley['seconds'])} the time of {name} (pyvale's SIMD CPU rasteriser) in q4 mode and "
            f"{_ratio(ex['seconds'], riley['seconds'])} in exact mode, on a face-on plate covering "
            f"{riley['coverage']:.0%} of the image, cubic interpolation, 4 spp ({_s(riley['seconds'])} s, "
            f"{_s(q4['seconds'])} s, {_s(ex['seconds'])} s).")



# ---- peer.json -------------------------------------------------------------------------------
def peer_rows(p: dict) -> str:
    """README: glsim GL against riley-raster (glsim bench peer): time ratios, times, mapping error, goals."""
    W, H = p["size"]
    ok = [r for r in p["rows"] if r["status"] == "ok"]
    missing = [r for r in p["rows"] if r["status"] != "ok"]
    lines = [f"`glsim bench peer` ({machine_line(p['machine'])}, {p['date'][:10]}): the same plate, "
             f"{p['elements'][0]}×{p['elements'][1]} quad4, {W}×{H}, Catmull–Rom cubic, {p['spp']} spp, without and "
             f"with k1 = −0.1; median of {p['reps']} interleaved repetitions; mapping error: each renderer's "
             "material point per pixel centre against the float64 oracle's, in camera px (riley from its ξ/η "
             "maps, its element taken from the oracle's)."
             + ("" if not missing else f" riley-raster: {missing[0]['status']} in this run."), "",
             "| renderer | k1 | glsim / riley time | riley / glsim time | time (s) | mapping RMS / max (camera px) "
             "| grey RMS vs oracle |", "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['renderer']} | {r['k1']:g} | {_s(r['glsim_over_riley'])} | {_s(r['riley_over_glsim'])} | "
              f"{_s(r['seconds'])} | {_s(r['map_rms_px'])} / {_s(r['map_max_px'])} | {_s(r['grey_rms'])} |" for r in ok]
    lines += ["", "Issue 12's goals in that run:", "", "| goal | measured | met |", "|---|---|---|"]
    lines += [f"| {g['goal']} | {g['measured']} | {'not measured' if g['met'] is None else 'yes' if g['met'] else 'no'} |"
              for g in p["goals"]]
    return "\n".join(lines)

# ---- effects.json ----------------------------------------------------------------------------
def effects(eff: dict) -> str:
    rows = {(r["backend"], r["effects"]): r["seconds"] for r in eff["records"]}
    g, c = (lambda e: rows["gl", e]), (lambda e: rows["cpu", e])
    inc = ", ".join(f"{name} {100 * (g(e) - g('none')) / g('none'):+.0f} %"
                    for e, name in (("lighting", "lighting"), ("optics", "depth of field"), ("noise", "noise")))
    return (f"Same run, bulge stereo pair at {eff['size'][0]}×{eff['size'][1]}, exact mode: on GL, {inc} over the "
            f"effect-free image, all three {_ratio(g('all'), g('none'))} its time; the CPU oracle takes "
            f"{_ratio(c('none'), g('none'))} GL's time without effects and {_ratio(c('all'), g('all'))} with all. "
            f"Absolute: GL {_s(g('none'))} s and {_s(g('all'))} s per image, CPU {_s(c('none'))} s and {_s(c('all'))} s "
            f"({machine_line(eff['machine'])}, {eff['date'][:10]}).")


def effects_dof(eff: dict) -> str:
    """docs/effects.md: every GL depth-of-field scheme against the oracle's exact 2-D gather."""
    from glsim.evaluation.effects import dof_table
    return dof_table(eff["dof"])


def effects_dof_facts(eff: dict) -> str:
    """docs/effects.md: the depth-of-field accuracy and cost in one paragraph."""
    rows, goal = eff["dof"], eff["dof_goal"]

    def worst(pick):
        return max(r["max_error"] for r in rows if pick(r))
    default = worst(lambda r: (r["kernel"], r["scheme"]) in (("gaussian", "expansion"), ("disk", "gather")))
    exact = worst(lambda r: r["scheme"] in ("gather", "hybrid"))
    sep = [r for r in rows if r["scheme"] == "separable"]
    hard = sorted({r["scene"] for r in rows} - {"bulge"})
    bulge = {r["scheme"]: r for r in rows if r["scene"] == "bulge" and r["kernel"] == "gaussian"}
    t = {r["scheme"]: r["seconds"] for r in rows if r["scene"] == "hole" and r["kernel"] == "gaussian"}
    size = next(r["size"] for r in rows if r["scene"] == "hole")
    blur = {s: next(r["blur_px"] for r in rows if r["scene"] == s) for s in ("bulge", "hole")}
    return (f"Against the oracle's exact 2-D gather, at every covered pixel of the bulge pair and of the scenes "
            f"{', '.join(hard)}, GL's default depth of field (`expansion` for the Gaussian, the 2-D gather for the disk) "
            f"errs by at most {_s(default)} of full scale ({_s(255 * default)} grey levels of 8 bit; goal {_s(goal)}), "
            f"`gather` and `hybrid` by {_s(exact)}; the separable pair by up to {_s(max(r['max_error'] for r in sep))} "
            f"({sum(r['over_goal'] for r in sep)} pixels beyond the goal). Time per image with depth of field only, "
            f"relative to the separable pair in the same run: bulge at {eff['size'][0]}×{eff['size'][1]} "
            f"(σ {_s(blur['bulge'][0])}–{_s(blur['bulge'][1])} px) expansion {_ratio(bulge['expansion']['seconds'], bulge['separable']['seconds'])}, gather "
            f"{_ratio(bulge['gather']['seconds'], bulge['separable']['seconds'])}, hybrid "
            f"{_ratio(bulge['hybrid']['seconds'], bulge['separable']['seconds'])}; hole at {size[0]}×{size[1]} "
            f"(σ {_s(blur['hole'][0])}–{_s(blur['hole'][1])} px) {_ratio(t['expansion'], t['separable'])}, {_ratio(t['gather'], t['separable'])} and "
            f"{_ratio(t['hybrid'], t['separable'])} ({machine_line(eff['machine'])}, {eff['date'][:10]}).")


# ---- verify.json -----------------------------------------------------------------------------
def verify_table(ver: dict) -> str:
    runs = {r["name"]: r for r in ver["runs"]}
    quad, aff = runs["quadratic"], runs["table3"]
    lines = ["| state | dir | glsim + pyvale, quadratic subsets: mean / std (px) | affine (Table 3) | paper (Tables 4–5) |",
             "|---|---|---|---|---|"]
    for sq, sa in zip(quad["states"], aff["states"]):
        for rq, ra in zip(sq["rows"], sa["rows"]):
            if rq["dir"] not in "XYZ":
                continue
            paper = ver["paper_px"][sq["label"]][rq["dir"]]
            lines.append(f"| {sq['label']} | {rq['dir']} | {_s(rq['mean_px'])} / {_s(rq['std_px'])} | "
                         f"{_s(ra['mean_px'])} / {_s(ra['std_px'])} | {_s(paper[0], 3)} / {_s(paper[1], 3)} |")
    return "\n".join(lines)


def verify_runs_table(ver: dict) -> str:
    """Every DIC run side by side (bold: outside the goal), the paper's figures, subsets compared."""
    goal, runs = ver["goal_px"], ver["runs"]

    def cell(x, limit):
        return f"**{_s(x)}**" if abs(x) > limit else _s(x)
    head = "| state | dir | " + " | ".join(f"{r['name']} mean | {r['name']} std" for r in runs) + " | paper mean | paper std |"
    lines = [head, "|" + "---|" * (4 + 2 * len(runs))]
    for i, state in enumerate(runs[0]["states"]):
        for j, row in enumerate(state["rows"]):
            if row["dir"] not in ("X", "Y", "Z", "W"):
                continue
            cells = []
            for r in runs:
                x = r["states"][i]["rows"][j]
                cells += [cell(x["mean_px"], goal["mean"]), cell(x["std_px"], goal["std"])]
            paper = ver["paper_px"].get(state["label"], {}).get(row["dir"])
            label = "W (displ.)" if row["dir"] == "W" else row["dir"]
            lines.append(f"| {state['label']} | {label} | " + " | ".join(cells) + " | "
                         + (f"{_s(paper[0], 3)} | {_s(paper[1], 3)}" if paper else "– | –") + " |")
    lines += ["", "Subsets compared: " + ", ".join(f"{r['n_compared']}/{r['n_subsets']} ({r['name']})" for r in runs)
              + f". Bold: outside the goal (|mean| ≤ {goal['mean']:g} px, std ≤ {goal['std']:g} px)."]
    return "\n".join(lines)


# ---- verify.json, sweep.json: prose figures of docs/verify.md ----------------------------------
def _vrow(run: dict, label: str, d: str) -> dict:
    state = next(s for s in run["states"] if s["label"] == label)
    return next(r for r in state["rows"] if r["dir"] == d)


def verify_scale(ver: dict) -> str:
    """docs/verify.md: the scale the results are given in, and the goal."""
    m = ver["runs"][0]["mm_per_px"]
    return (f"DIC − imposed, px (M = {m:.4g} mm/px, mean Z / √(fx·fy) over the compared centres in the reference "
            f"state; the paper: ≈ 0.08); goal |mean| ≤ {ver['goal_px']['mean']:g} and std ≤ {ver['goal_px']['std']:g} px.")


def verify_choices(ver: dict) -> str:
    """docs/verify.md: what the choices give in the run of verify.json."""
    runs = {r["name"]: r for r in ver["runs"]}
    a, a8, q = runs["table3"], runs["table3-8bit"], runs["quadratic"]
    left = q["n_subsets"] - q["n_compared"]
    return (f"In the run of `bench/results/verify.json` ({ver['size'][0]}×{ver['size'][1]}, σ = "
            f"{ver['speckle_sigma_px']:g} px low-pass, {ver['mesh_divisions']} divisions): 8-bit quantisation raises the "
            f"reference-state Z std from {_s(_vrow(a, 'undeformed', 'Z')['std_px'])} to "
            f"{_s(_vrow(a8, 'undeformed', 'Z')['std_px'])} px and the Y std from {_s(_vrow(a, 'undeformed', 'Y')['std_px'])} "
            f"to {_s(_vrow(a8, 'undeformed', 'Y')['std_px'])} px (table3 vs table3-8bit); with the quadratic shape function "
            f"the reference-state Z std is {_s(_vrow(q, 'undeformed', 'Z')['std_px'])} px and the deformed-state Z std "
            f"{_s(_vrow(q, 'deformed', 'Z')['std_px'])} px; {left} of its {q['n_subsets']} subsets "
            f"({100 * left / q['n_subsets']:.0f} %) are left out (not valid in both states: not converged, or ZNCC below "
            "the threshold).")


def verify_facts(ver: dict) -> str:
    """docs/verify.md: the two shape functions against the goal and the paper."""
    runs = {r["name"]: r for r in ver["runs"]}
    q, a, goal = runs["quadratic"], runs["table3"], ver["goal_px"]
    xyz = [(s["label"], r) for s in q["states"] for r in s["rows"] if r["dir"] in "XYZ"]
    every = [r for s in q["states"] for r in s["rows"] if r["dir"] in "XYZW"]
    paper = ver["paper_px"]
    ratios = [paper[lab][r["dir"]][1] / r["std_px"] for lab, r in xyz]
    miss = [(s["label"], r) for s in a["states"] for r in s["rows"] if r["dir"] in "XYZ"
            and (abs(r["mean_px"]) > goal["mean"] or r["std_px"] > goal["std"])]
    what = "; ".join(f"{lab} {r['dir']} " + ", ".join(
        ([f"mean {_s(r['mean_px'])}"] if abs(r["mean_px"]) > goal["mean"] else [])
        + ([f"std {_s(r['std_px'])}"] if r["std_px"] > goal["std"] else [])) for lab, r in miss)
    return "\n".join([
        f"- With the **quadratic** shape function every row meets the goal: |means| ≤ "
        f"{_s(max(abs(r['mean_px']) for r in every))} px, stds ≤ {_s(max(r['std_px'] for r in every))} px; the stds "
        f"of X, Y, Z are {min(ratios):.0f} to {max(ratios):.0f} times below the paper's.",
        f"- With the paper's **affine** shape function (Table 3) these miss the goal (px): {what}."])


def verify_timing(ver: dict) -> str:
    """docs/verify.md: render and DIC times of the run, the DIC relative to the render."""
    r = ver["render_seconds"]
    return (f"Same run ({machine_line(ver['machine'])}, {ver['date'][:10]}): the DIC takes "
            + ", ".join(f"{_ratio(x['dic_seconds'], r)} ({x['name']})" for x in ver["runs"])
            + f" the time of rendering the four images and the truth maps ({_s(r)} s; DIC "
            + ", ".join(f"{_s(x['dic_seconds'])} s" for x in ver["runs"]) + ").")


def sweep_facts(sw: dict, acc: dict) -> str:
    """docs/verify.md: what the sweep shows, from sweep.json (and accuracy.json for the mapping errors)."""
    by = {(r["sequence"], r["run"]): r for r in sw["results"]}
    s0, s1 = sw["runs"][0]["name"], sw["runs"][1]["name"]
    model, m4 = by["model", s0], by["model-spp4", s0]
    rows = model["rows"]
    peak = max(rows, key=lambda x: x["std_u"])
    half = next(x for x in rows if abs(x["shift_px"] - 0.5) < 1e-9)
    ends = [x["bias_u"] for x in (rows[0], rows[-1])]
    below = all(x["bias_u"] <= 0 for x in rows if 0 < x["shift_px"] < 0.5)
    proc, bsp, bsp4 = by["exact-procedural", s0], by["exact-bspline3", s0], by["exact-bspline3-spp4", s0]
    app = [x["apparent_u"] for x in proc["rows"]]
    zero = [x["shift_px"] for x in bsp["rows"] if abs(x["apparent_u"]) < 1e-8]
    ex = [x["bias_u"] for x in bsp["rows"]]
    coincide = max(abs(a - b) for seq in ("fast-bspline3", "q4-bspline3")
                   for a, b in zip(ex, (x["bias_u"] for x in by[seq, s0]["rows"])))
    mp = {m: _record(acc, "gl", m, "bspline3", 1)["map_rms_px"] for m in ("fast", "q4")}
    return "\n".join([
        f"- **The DIC's own S-curve** (pyvale on the exact model images): ±{_s(model['max_abs_bias_u'])} px, "
        + (f"zero at {rows[0]['shift_px']:g} and {rows[-1]['shift_px']:g} px" if ends == [0, 0] else
           f"{_s(ends[0])} and {_s(ends[1])} at {rows[0]['shift_px']:g} and {rows[-1]['shift_px']:g} px") + " and "
        + f"{_s(half['bias_u'])} px at 0.5 px, {'negative' if below else 'not always negative'} below 0.5 px at 1 spp; "
        f"the std peaks at {peak['shift_px']:g} px ({_s(peak['std_u'])} px with {model['subset_size']}-px subsets, "
        f"{_s(by['model', s1]['max_std_u'])} with {by['model', s1]['subset_size']}). At 4 spp the bias is "
        f"±{_s(m4['max_abs_bias_u'])} px, the largest std {_s(m4['max_std_u'])} px: most of the DIC's error on this "
        "speckle comes from its 1-px dot edges aliasing at 1 spp. The subset size changes the std, not the bias.",
        f"- **exact/procedural has no generator bias**: its images equal the model images (grey RMS "
        f"{_s(255 * proc['max_grey_rms_vs_model'])} of an 8-bit level, float32 evaluation in the shader; the CPU oracle "
        f"matches to 2 float32 ulp, `tests/test_sweep.py`), pyvale reads them within {_s(proc['max_abs_gen_u'])} px of "
        f"the model, and the generator-alone shift error is {_s(min(app))} to {_s(max(app))} px at every shift "
        "(float32 reference coordinates in GL).",
        f"- **bspline3 interpolation displaces the speckle**: the generator-alone error reaches "
        f"±{_s(bsp['max_abs_apparent_u'])} px (zero where the reference coordinates are whole pixels of the "
        f"2×-oversampled reference image: {', '.join(f'{z:g}' for z in zero)} px), ±{_s(bsp4['max_abs_apparent_u'])} px "
        f"at 4 spp; it is a {_s(255 * bsp['max_grey_rms_vs_model'])}-level (8-bit) RMS grey error. pyvale, which "
        f"compares the images only with each other, reads up to {_s(bsp['max_abs_gen_u'])} px of it "
        f"({_s(bsp4['max_abs_gen_u'])} px at 4 spp), the size of `glsim verify`'s 1e-3 px goal. (This is the "
        "unfiltered speckle, the hardest case; `glsim verify`'s σ = 1 px low-passed reference has much less content "
        "near the reference's Nyquist frequency.)",
        "- **The modes are not separated by this sweep**: a plate square to a distortion-free camera projects "
        f"affinely, which `fast` and `q4` reproduce exactly; their DIC bias curves coincide with `exact`'s to "
        f"{_s(coincide)} px. Their mapping errors ({_s(mp['fast'])} and {_s(mp['q4'])} px RMS on the bulge, "
        "`accuracy.json`) appear only with perspective, curvature or distortion."])


def sweep_frontier(acc: dict, sw: dict) -> str:
    """docs/verify.md: the frontier's ends and which default the data support (accuracy.json, sweep.json)."""
    ex, q4 = _record(acc, "gl", "exact", "bspline3", 1), _record(acc, "gl", "q4", "bspline3", 1)
    fast = min((r for r in acc["records"] if r["backend"] == "gl" and r["mode"] == "fast" and r["spp"] == 1
                and r["precision"] == "fp64"), key=lambda r: r["seconds"])
    proc = _record(acc, "gl", "exact", "procedural", 1)
    spp = max(r["spp"] for r in acc["records"])
    b16 = _record(acc, "gl", "exact", "bspline3", spp)
    by = {(r["sequence"], r["run"]): r for r in sw["results"]}
    s0 = sw["runs"][0]["name"]
    bsp, p512, b512 = by["exact-bspline3", s0], by["exact-procedural", s0], by["exact-bspline3", s0]
    approx = [r for r in acc["records"] if r["backend"] == "gl" and r["mode"] in ("fast", "q4")]
    lo, hi = min(r["map_rms_px"] for r in approx), max(r["map_max_px"] for r in approx)
    W, H = acc["size"]
    return (f"From `accuracy.json` ({machine_line(acc['machine'])}, {acc['date'][:10]}): the mapping front is `fast` "
            f"({_s(fast['seconds'])} s, {_s(fast['map_rms_px'])} px RMS) then `exact` ({_s(ex['seconds'])} s, "
            f"{_s(ex['map_rms_px'])} px); the grey front ends in `exact`/`procedural` ({_s(proc['seconds'])} s, "
            f"{_s(proc['speckle_rms'])} levels at 1 spp), which `bspline3` does not approach even at {spp} spp "
            f"({_s(b16['speckle_rms'])} levels, {_s(b16['seconds'])} s).\n\n"
            f"**Which default the data support**: mode `exact` — `fast` and `q4` take {_ratio(fast['seconds'], ex['seconds'])} "
            f"and {_ratio(q4['seconds'], ex['seconds'])} its time but misplace the speckle by {lo / 1e-3:.0f} (RMS) to "
            f"{hi / 1e-3:.0f} (max) times the 1e-3 px a sub-pixel DIC check needs. For the interpolation, `procedural` "
            f"whenever the reference is the built-in generator: it removes a generator bias of up to "
            f"{_s(bsp['max_abs_apparent_u'])} px ({_s(bsp['max_abs_gen_u'])} px as pyvale reads it) for "
            f"{_ratio(proc['seconds'], ex['seconds'])} the time of `bspline3` ({_s(proc['seconds'])} against "
            f"{_s(ex['seconds'])} s per {W}×{H} image; {_ratio(p512['render_seconds_median'], b512['render_seconds_median'])}, "
            f"{_s(p512['render_seconds_median'])} against {_s(b512['render_seconds_median'])} s at "
            f"{sw['size'][0]}×{sw['size'][1]} in the sweep).")


def sweep_timing(sw: dict) -> str:
    """docs/verify.md: where the sweep's time goes."""
    dic = [r["dic_seconds"] for r in sw["results"]]
    t = sw["seconds"]
    return (f"**Timings** ({machine_line(sw['machine'])}, {sw['date'][:10]}): rendering the images, the model images "
            f"and the files {_s(t['render_and_write'])} s, generator-alone fits {_s(t['apparent_shift'])} s, pyvale "
            f"{_s(sum(dic))} s ({len(dic)} calls of {_s(min(dic))}–{_s(max(dic))} s).")


# ---- sweep.json, sweep_backends.json ---------------------------------------------------------
def sweep(sw: dict, backends: dict) -> str:
    by = {(r["sequence"], r["run"]): r for r in sw["results"]}
    run = sw["runs"][0]["name"]
    model, proc, bsp = by["model", run], by["exact-procedural", run], by["exact-bspline3", run]
    noise = [r["max_std_u"] for r in sw["results"] if r["source"] == "model"]
    exact_rows = [r for r in backends["rows"] if r["sequence"].startswith("exact")]
    return (f"The DIC's own S-curve on the exactly shifted model images is ±{_s(model['max_abs_bias_u'])} px at one "
            f"sample per pixel (subset {model['subset_size']} px). `exact` with the procedural speckle adds "
            f"{_s(proc['max_abs_gen_u'])} px to it; B-spline interpolation of the generated reference moves the speckle "
            f"by up to {_s(bsp['max_abs_apparent_u'])} px (zero at whole and half pixels), of which the DIC sees "
            f"{_s(bsp['max_abs_gen_u'])} px. The same sweep rendered by the CPU oracle differs from GL by at most "
            f"{_s(max(r['max_delta_bias_px'] for r in backends['rows']))} px in bias "
            f"({_s(max(r['max_delta_bias_px'] for r in exact_rows))} px in exact mode), against the DIC's own scatter "
            f"of {_s(min(noise))}–{_s(max(noise))} px.")


def sweep_subsets(sw: dict) -> str:
    """docs/verify.md: how many of the sweep's subsets are valid at every shift."""
    parts = []
    for run in sw["runs"]:
        rs = [r for r in sw["results"] if r["run"] == run["name"]]
        parts.append(f"{min(r['n_valid'] for r in rs)} of {max(r['n_subsets'] for r in rs)} ({run['name']})")
    return "Subsets valid at every shift, in every sequence (`sweep.json`): " + ", ".join(parts) + "."


def sweep_table(sw: dict) -> str:
    """Per sequence: render time, DIC bias and std per subset size, generator share and alone (px)."""
    runs = [r["name"] for r in sw["runs"]]
    by = {(r["sequence"], r["run"]): r for r in sw["results"]}
    seqs = list(dict.fromkeys(r["sequence"] for r in sw["results"]))
    lines = [f"| sequence | render (s) | DIC max abs bias {' / '.join(runs)} | DIC max std {' / '.join(runs)} "
             "| DIC generator share | generator alone |", "|---|---|---|---|---|---|"]
    for s in seqs:
        rs = [by[s, r] for r in runs if (s, r) in by]
        first = rs[0]
        render = (f"(numpy {_s(first['render_seconds_median'])})" if first["source"] == "model"
                  else _s(first["render_seconds_median"]))
        lines.append(f"| {s} | {render} | {' / '.join(_s(r['max_abs_bias_u']) for r in rs)} | "
                     f"{' / '.join(_s(r['max_std_u']) for r in rs)} | {_s(first['max_abs_gen_u'])} | "
                     f"{_s(first['max_abs_apparent_u'])} |")
    return "\n".join(lines)


# ---- calib_accuracy.json ---------------------------------------------------------------------
def calibration(cal: dict) -> str:
    runs = cal["runs"]
    f = runs["full"]
    plain, fixed = f["bias_iterations_0"], f["bias_iterations_1"]

    def worst(r, keys):
        return max(abs(r[k]) for k in keys)
    rel, pp, k1 = ("fx1_rel", "fy1_rel", "fx2_rel", "fy2_rel"), ("cx1_px", "cy1_px", "cx2_px", "cy2_px"), ("k1_1_rel", "k1_2_rel")
    W, H = f["image_size"]
    text = (f"On a perfect target at {W}×{H} detection errs by {_s(f['detection']['centroid']['mean'])} px mean "
            f"({_s(f['detection']['centroid']['max'])} max) against the true centroid without noise")
    noisy = runs.get("full_noise2")
    if noisy:
        text += (f" and by {_s(noisy['detection']['centroid']['mean'])} px mean "
                 f"({_s(noisy['detection']['centroid']['max'])} max) with {noisy['noise_percent']:g} % noise")
    text += (f", while the centroid sits {_s(f['detection']['projected']['mean'])} px (mean; "
             f"{_s(f['detection']['projected']['max'])} max) from the projected centre (perspective bias). "
             f"`glsim calib run` corrects that bias with one extra pass by default: with {f['pairs']} pairs and no noise, "
             f"fx/fy within {_s(100 * worst(fixed, rel))} %, cx/cy within {_s(worst(fixed, pp))} px, "
             f"k1 within {_s(100 * worst(fixed, k1))} %, stereo translation {_s(fixed['T_norm_mm'])} mm, rotation "
             f"{_s(fixed['rotation_deg'])}°, RMS {_s(fixed['rms_px'])} px (plain OpenCV: cx/cy within "
             f"{_s(worst(plain, pp))} px, rotation {_s(plain['rotation_deg'])}°).")
    if noisy:
        c = noisy["bias_iterations_1"]
        text += (f" With {noisy['noise_percent']:g} % noise (`glsim calib library`'s default) and {noisy['pairs']} pairs: "
                 f"cx/cy within {_s(worst(c, pp))} px, k1 within {_s(100 * worst(c, k1))} %, stereo translation "
                 f"{_s(c['T_norm_mm'])} mm, rotation {_s(c['rotation_deg'])}°, RMS {_s(c['rms_px'])} px")
        more = [r for k, r in runs.items() if k.startswith("full_noise2_")]
        if more:
            m = more[0]["bias_iterations_1"]
            text += (f"; with {more[0]['pairs']} pairs: cx/cy within {_s(worst(m, pp))} px, translation "
                     f"{_s(m['T_norm_mm'])} mm, rotation {_s(m['rotation_deg'])}°")
        text += "."
    return text


def calibration_detection(cal: dict) -> str:
    lines = ["| image size | noise | pairs | vs true centroid: mean / RMS / max (px) | vs projected centre: mean / max (px) |",
             "|---|---|---|---|---|"]
    seen = set()
    for run in cal["runs"].values():
        key = (tuple(run["image_size"]), run.get("noise_percent", 0), run["seed"])
        if key in seen:              # the same library measured again with more pairs
            continue
        seen.add(key)
        c, p = run["detection"]["centroid"], run["detection"]["projected"]
        lines.append(f"| {run['image_size'][0]} × {run['image_size'][1]} | {run.get('noise_percent', 0):g} % | "
                     f"{run['pairs']} | {_s(c['mean'])} / {_s(c['rms'])} / {_s(c['max'])} | {_s(p['mean'])} / {_s(p['max'])} |")
    return "\n".join(lines)


def calibration_accuracy(cal: dict) -> str:
    """The calibration errors of every run of examples/calib_accuracy.py (bias-corrected, and
    plain OpenCV in brackets)."""
    rel, pp, k1 = ("fx1_rel", "fy1_rel", "fx2_rel", "fy2_rel"), ("cx1_px", "cy1_px", "cx2_px", "cy2_px"), ("k1_1_rel", "k1_2_rel")

    def worst(r, keys):
        return max(abs(r[k]) for k in keys)
    runs = list(cal["runs"].values())
    head = ["| | " + " | ".join(f"{r['image_size'][0]} × {r['image_size'][1]}, {r.get('noise_percent', 0):g} % noise, "
                                f"{r['pairs']} pairs ({r['bias_iterations_1']['pairs_used']} used)" for r in runs) + " |",
            "|---|" + "---|" * len(runs)]
    rows = [("fx, fy (both cameras)", lambda r: f"{_s(100 * worst(r, rel))} %"),
            ("cx, cy (both cameras)", lambda r: f"{_s(worst(r, pp))} px"),
            ("k1 (worse camera)", lambda r: f"{_s(100 * worst(r, k1))} %"),
            ("\\|ΔT\\|", lambda r: f"{_s(r['T_norm_mm'])} mm"),
            ("rotation", lambda r: f"{_s(r['rotation_deg'])}°"),
            ("RMS", lambda r: f"{_s(r['rms_px'])} px")]
    lines = head + [f"| {name} | " + " | ".join(f"{f(r['bias_iterations_1'])} ({f(r['bias_iterations_0'])})" for r in runs)
                    + " |" for name, f in rows]
    spread = [(r, r["spread_at_this_detection_noise"]) for r in runs if r.get("spread_at_this_detection_noise")]
    if spread:
        lines += ["", "The spread a calibration of these views has at the measured detection noise (true centroids + "
                  "Gaussian noise of the measured scatter, bias-corrected; median / 90th percentile):", "",
                  "| | max \\|cx, cy\\| (px) | \\|ΔT\\| (mm) | rotation (°) | draws meeting cx, cy ≤ 0.05 px, \\|ΔT\\| ≤ "
                  "0.005 mm and rotation ≤ 0.001° |", "|---|---|---|---|---|"]
        for r, s_ in spread:
            lines.append(f"| {r.get('noise_percent', 0):g} %, {r['pairs']} pairs (σ = {_s(s_['sigma_per_axis_px'])} px "
                         f"per axis) | {_s(s_['cxcy_max_px']['median'])} / {_s(s_['cxcy_max_px']['p90'])} | "
                         f"{_s(s_['T_norm_mm']['median'])} / {_s(s_['T_norm_mm']['p90'])} | "
                         f"{_s(s_['rotation_deg']['median'])} / {_s(s_['rotation_deg']['p90'])} | "
                         f"{100 * s_['fraction_within_goals']:.0f} % of {s_['draws']} |")
    return "\n".join(lines)


def calibration_targets(cal: dict) -> str:
    """Target types at 0 and 2 % noise (examples/calib_accuracy.py)."""
    lines = ["| target | noise | views found | pairs used | detection vs projected point: mean / max (px) | "
             "cx, cy max (px) | k1 max | \\|ΔT\\| (mm) | rotation (°) | RMS (px) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in cal.get("targets", []):
        d = r["detection"]["projected"]
        c = r["detection"].get("centroid")
        det = f"{_s(d['mean'])} / {_s(d['max'])}" + (f" (true centroid: {_s(c['mean'])} / {_s(c['max'])})" if c else "")
        lines.append(f"| {r['target']} ({r['points']} points) | {r['noise_percent']:g} % | {r['views_found']}/{r['views']} | "
                     f"{r['pairs_used']} | {det} | {_s(r['cxcy_max_px'])} | "
                     f"{_s(100 * r['k1_max_rel'])} % | {_s(r['T_norm_mm'])} | {_s(r['rotation_deg'])} | {_s(r['rms_px'])} |")
    return "\n".join(lines)


def calibration_estimators(det: dict) -> str:
    """Dot-centre estimators against the true centroid at each noise level (examples/calib_detection.py)."""
    names = {"fit": "model fit (default)", "centroid": "grey-level centroid, ±0.45 pitch (before)",
             "centroid-dot": "grey-level centroid, dot + 3 px", "edge-ellipse": "ellipse through sub-pixel edge points",
             "blob": "OpenCV blob centres"}
    main = [r for r in det["runs"] if r["px_per_mm"] == det["px_per_mm"]]
    lines = ["| estimator | " + " | ".join(f"{r['noise_percent']:g} % noise: mean / max (px)" for r in main) + " |",
             "|---|" + "---|" * len(main)]
    for m in det["methods"]:
        lines.append(f"| {names.get(m, m)} | " + " | ".join(
            f"{_s(r['methods'][m]['mean'])} / {_s(r['methods'][m]['max'])}" for r in main) + " |")
    lines.append("| Cramér–Rao bound (mean) | " + " | ".join(
        _s(r["bound"]["mean"]) if r["noise_percent"] > 0 else "–" for r in main) + " |")
    other = [r for r in det["runs"] if r["px_per_mm"] != det["px_per_mm"]]
    if other:
        lines += ["", f"The same at {other[0]['px_per_mm']:g} px/mm (reference pixels of "
                  f"{_s(det['image_px_per_ref_px'][str(other[0]['px_per_mm'])])} image px): model fit "
                  + ", ".join(f"{_s(r['methods']['fit']['mean'])} / {_s(r['methods']['fit']['max'])} px at "
                              f"{r['noise_percent']:g} %" for r in other)
                  + "; grey-level centroid " + ", ".join(f"{_s(r['methods']['centroid']['mean'])} / "
                                                         f"{_s(r['methods']['centroid']['max'])} px" for r in other) + "."]
    return "\n".join(lines)


# ---- calib_detection.json, calib_accuracy.json: prose figures of docs/calib.md ---------------
def _det_run(det: dict, px_per_mm: float, noise: float = 0) -> dict:
    return next(r for r in det["runs"] if r["px_per_mm"] == px_per_mm and r["noise_percent"] == noise)


def calibration_resolution(det: dict) -> str:
    """docs/calib.md, *Reference resolution*: the model fit's noise-free error at both reference resolutions."""
    main = det["px_per_mm"]
    other = next(r["px_per_mm"] for r in det["runs"] if r["px_per_mm"] != main)
    W, H = det["image_size"]
    return (f"Measured (`bench/results/calib_detection.json`): at {W} × {H} with {other:g} px/mm "
            f"({_s(det['image_px_per_ref_px'][str(other)])} image px per reference px) the model fit below errs by "
            f"{_s(_det_run(det, other)['methods']['fit']['mean'])} px (mean) without noise, at {main:g} px/mm by "
            f"{_s(_det_run(det, main)['methods']['fit']['mean'])} px.")


def calibration_estimator_facts(det: dict) -> str:
    """docs/calib.md: what the estimator table says, its figures from the same file."""
    main = det["px_per_mm"]
    other = next(r["px_per_mm"] for r in det["runs"] if r["px_per_mm"] != main)
    noisy = [r for r in det["runs"] if r["px_per_mm"] == main and r["noise_percent"] > 0]
    ratio = [r["methods"]["fit"]["mean"] / r["bound"]["mean"] for r in noisy]
    two = _det_run(det, main, 2)
    zero = _det_run(det, main)["methods"]
    return (f"The model fit's mean error is {_s(min(ratio), 3)}–{_s(max(ratio), 3)} times the Cramér–Rao bound at "
            f"{', '.join(format(r['noise_percent'], 'g') for r in noisy)} % noise, so at 2 % noise its "
            f"{_s(two['methods']['fit']['mean'])} px is the information limit of these images: the issue's goal of "
            "≤ 0.005 px mean sits on the bound, and nothing but sharper or less noisy images (or larger dots) goes "
            "below it. The grey-level centroid is exact without noise but takes in the noise of every pixel of its "
            "window, with the lever arm of its distance from the centre; the three 3 mm markers, smaller, suffer "
            "most. The dot-sized window removes most of that, the model fit the rest. Edge points at half contrast "
            f"along rays carry the bias of interpolating a sharp edge ({_s(zero['edge-ellipse']['mean'])} px mean "
            f"without noise); OpenCV's blob centres are thresholded contours ({_s(zero['blob']['mean'])} px). Without "
            "noise the fit's residual is the reference raster showing through (see *Reference resolution*): "
            f"{_s(zero['fit']['mean'])} px at {main:g} px/mm against "
            f"{_s(_det_run(det, other)['methods']['fit']['mean'])} px at {other:g} px/mm.")


def calibration_spread_facts(cal: dict) -> str:
    """docs/calib.md: what the spread table says about the issue's goals, from calib_accuracy.json."""
    runs = cal["runs"]
    pp = ("cx1_px", "cy1_px", "cx2_px", "cy2_px")
    full, ten = runs["full"], runs["full_noise2"]
    s10 = ten["spread_at_this_detection_noise"]
    more = [r for k, r in runs.items() if k.startswith("full_noise2_") and r.get("spread_at_this_detection_noise")]
    own = ten["bias_iterations_1"]
    goals = {"cx, cy": max(abs(own[k]) for k in pp) <= 0.05, "the rotation": own["rotation_deg"] <= 0.001,
             "|ΔT|": own["T_norm_mm"] <= 0.005}
    met, missed = [k for k, v in goals.items() if v], [k for k, v in goals.items() if not v]
    own_text = (f"this library's own {ten['pairs']} pairs meet " + (" and ".join(met) if met else "none of them")
                + (f" but not {' and '.join(missed)}" if met and missed else ""))
    text = (f"Without noise the corrected calibration is limited by the detection's "
            f"{_s(full['detection']['centroid']['mean'])} px (mean); fed the *true* centroids it is exact (above). "
            f"With 2 % noise the detection is at its Cramér–Rao bound ({_s(s10['sigma_per_axis_px'])} px per axis), "
            f"and the spread table says what {ten['pairs']} pairs can then give: the same views with the true "
            f"centroids plus Gaussian noise of the measured scatter. The issue's goals at 2 % and {ten['pairs']} pairs "
            "(cx, cy ≤ 0.05 px, |ΔT| ≤ 0.005 mm, rotation ≤ 0.001° together) are met by "
            f"{100 * s10['fraction_within_goals']:.0f} % of those {s10['draws']} draws; {own_text}.")
    for r in more:
        s = r["spread_at_this_detection_noise"]
        text += (f" With {r['pairs']} pairs {100 * s['fraction_within_goals']:.0f} % of the draws meet all three "
                 f"(medians {_s(s['cxcy_max_px']['median'])} px, {_s(s['T_norm_mm']['median'])} mm, "
                 f"{_s(s['rotation_deg']['median'])}°)")
    big = max((r for r in runs.values() if r.get("noise_percent")), key=lambda r: r["detection"]["centroid"]["n"])
    c = big["detection"]["centroid"]
    plain = [r["bias_iterations_0"]["rotation_deg"] for r in runs.values()]
    return text + (f". The errors of one library are one draw from that spread: the detection's errors carry no "
                   f"measurable bias (their mean over {c['n']} dots is {_s(max(abs(b) for b in c['bias']), 1)} px per "
                   f"axis at most). Without the correction the rotation error ({_s(min(plain), 1)}–"
                   f"{_s(max(plain), 1)}° over the runs of this file) comes from the target (5 mm dots), not from "
                   "the pixel size: the perspective bias, not the dot detection, limits a plain calibration on "
                   "synthetic images.")


def calibration_corner_facts(cal: dict) -> str:
    """docs/calib.md: the boards' corners against the dots' model fit, without noise."""
    t = [r for r in cal.get("targets", []) if r["noise_percent"] == 0]
    corners = [r for r in t if r["target"] != "dots"]
    dots = next(r for r in t if r["target"] == "dots")["detection"]["centroid"]["mean"]
    means = [r["detection"]["projected"]["mean"] for r in corners]
    cb = next(r for r in corners if r["target"] == "chessboard")["detection"]["projected"]["bias"]
    return (f"The boards' corners (findChessboardCornersSB; CharucoDetector refined on the smoothed image) leave "
            f"{_s(min(means))}–{_s(max(means))} px (mean) without noise (the "
            f"chessboard's findChessboardCornersSB also a mean offset of {cb[0]:+.2g} / {cb[1]:+.2g} px in x / y), "
            f"{_ratio(min(means), dots)}–{_ratio(max(means), dots)} the dots' {_s(dots)} px against their true "
            "centroids, and the calibrations follow.")


def calibration_timing(cal: dict, det: dict) -> str:
    """docs/calib.md: render, detection and calibration times recorded by examples/calib_accuracy.py and
    examples/calib_detection.py."""
    runs = cal["runs"]
    size = lambda r: f"{r['image_size'][0]} × {r['image_size'][1]}"
    lines = [f"Recorded by `examples/calib_accuracy.py` and `examples/calib_detection.py` on "
             f"{machine_line(cal['machine'])} (shared; times vary with other jobs and by machine):", "",
             "| | time |", "|---|---|"]
    renders = {}
    for r in runs.values():
        if r.get("seconds_per_pair_render"):
            renders.setdefault(size(r), []).append(r["seconds_per_pair_render"])
    for k, v in renders.items():
        lines.append(f"| render of one pair (2 images), {k}, exact, 16 spp | "
                     + (f"{_s(min(v))}–{_s(max(v))} s" if len(set(v)) > 1 else f"{_s(v[0])} s") + " |")
    m = _det_run(det, det["px_per_mm"])["methods"]
    W, H = det["image_size"]
    lines.append(f"| detection per image, {W} × {H}: model fit / grey-level centroid (no noise) | "
                 f"{_s(m['fit']['seconds_per_image'])} s / {_s(m['centroid']['seconds_per_image'])} s |")
    for r in runs.values():
        a, b = r["bias_iterations_0"], r["bias_iterations_1"]
        lines.append(f"| one calibration, plain / bias-corrected: {b['pairs_used']} pairs at {size(r)}"
                     f"{', %g %% noise' % r['noise_percent'] if r.get('noise_percent') else ''} | "
                     f"{_s(a['seconds'])} s / {_s(b['seconds'])} s |")
    full = renders.get(f"{W} × {H}")
    if full:
        lines += ["", f"At these render times a 1000-pair library at {W} × {H} takes "
                  f"{_s(1000 * min(full) / 3600)}–{_s(1000 * max(full) / 3600)} hours to render (1000 × the time per pair)."]
    return "\n".join(lines)


def calibration_study(images: list[dict], fov: list[dict], quality: list[dict]) -> str:
    """docs/calib.md: the reduced study's findings from its CSV files (bench/results/calib_study/)."""
    import numpy as np
    from glsim.workflows.calib.study import summary
    # files written before the target_seed column held one target per σ
    images, fov, quality = ([{"target_seed": "0", **r} for r in rows] for rows in (images, fov, quality))
    si, sf, sq = summary(images), summary(fov), summary(quality)
    f = lambda rows, label, n: next(e for e in rows if e["label"] == label and e["n"] == n)
    n_lo, n_hi = min(e["n"] for e in si), max(e["n"] for e in si)
    lo, hi = f(si, "all", n_lo), f(si, "all", n_hi)

    def mean_abs(rows, label, n, p):
        return float(np.mean([abs(float(r[f"err_{p}"])) for r in rows
                              if r["label"] == label and int(float(r["n"])) == n and float(r["n_used"]) > 0]))
    nf = sorted({e["n"] for e in sf})
    k1 = [mean_abs(fov, "centre", n, "k1_1") / mean_abs(fov, "full", n, "k1_1") for n in nf]
    rms = [e["rms"] for e in sf]
    sig = sorted({e["label"] for e in sq}, key=float)
    nq = sq[0]["n"]
    q = [f(sq, s, nq) for s in sig]
    calibrations = sum(len([r for r in rows if float(r["n_used"]) > 0]) for rows in (images, fov, quality))
    targets = [len({r["target_seed"] for r in quality if r["label"] == s}) for s in sig[1:]]
    z = [abs(e["mean_err_cx1"]) / (e["std_cx1"] / e["runs"] ** 0.5) for e in q[1:]]
    return "\n".join([
        f"{calibrations} calibrations with the bias correction (rows of `study_images.csv`, `study_fov.csv`, "
        "`study_quality.csv`). What they show:", "",
        f"- **Number of pairs** (Fig. 11): the spread of every parameter falls from {n_lo} to {n_hi} pairs (std Fx "
        f"{_s(lo['std_fx1'])} → {_s(hi['std_fx1'])} px, κ1 {_s(lo['std_k1_1'])} → {_s(hi['std_k1_1'])}, Cx "
        f"{_s(lo['std_cx1'])} → {_s(hi['std_cx1'])} px, Tz {_s(lo['std_Tz'])} → {_s(hi['std_Tz'])} mm; "
        f"1/√n would give × {_s((n_lo / n_hi) ** 0.5)}); the mean Fx error at {n_hi} pairs is "
        f"{hi['mean_err_fx1']:+.2g} px.",
        f"- **Field of view** (Fig. 13, Table 7, Fig. 14): centre-only libraries give mean |κ1 error| "
        f"{_s(min(k1))}–{_s(max(k1))} times the full FOV's ({', '.join(str(n) for n in nf)} pairs) and, above all, "
        f"κ2/κ3 that are far off (mean κ3 error {f(sf, 'centre', nf[0])['mean_err_k3_1']:+.2g} against "
        f"{f(sf, 'full', nf[0])['mean_err_k3_1']:+.2g} for the full FOV at {nf[0]} pairs), while the RMS is the same "
        f"({_s(min(rms))}–{_s(max(rms))} px); the maximum epipolar distance over the FOV is "
        + " / ".join(f"{_s(f(sf, 'centre', n)['epipolar_max_px'])} px" for n in nf) + f" ({' / '.join(map(str, nf))} "
        "pairs) for centre-only against " + " / ".join(f"{_s(f(sf, 'full', n)['epipolar_max_px'])}" for n in nf)
        + " px for the full FOV — the paper's point that a good score does not prove a good calibration.",
        f"- **Target quality** (Figs 15, 16; {nq} pairs): the RMS grows with σ ("
        + ", ".join(_s(e["rms"]) for e in q) + f" px for σ = {', '.join(sig)} mm at about 0.5 mm/px), and so does "
        "the spread. Over " + " / ".join(map(str, targets)) + " printed targets per σ (the runs go round them) the "
        "*mean* errors grow too (Cx " + " / ".join(f"{e['mean_err_cx1']:+.2g}" for e in q[1:])
        + " px, std " + " / ".join(_s(e["std_cx1"]) for e in q[1:]) + " px; Tz "
        + " / ".join(f"{e['mean_err_Tz']:+.2g}" for e in q[1:]) + " mm): the mean Cx error is "
        + " / ".join(f"{x:.1f}" for x in z) + " standard errors from zero — each target's defects bias every "
        "calibration made with it, and this many targets do not average the bias out.",
    ])


# ---- scaling.json: docs/scaling.md -------------------------------------------------------------
def _sc_pts(sc: dict, key: str = "elements") -> list[dict]:
    return [r for r in sc[key] if "renderers" in r]


def _host(r: dict) -> list[float]:
    return [v["host_ms"] for v in r["renderers"].values() if v.get("host_ms") is not None]


def scaling_host(sc: dict) -> str:
    """docs/scaling.md: the host time per render over the element sweep."""
    pts = _sc_pts(sc)
    host = [h for r in pts for h in _host(r)]
    W, H = pts[0]["size"]
    return (f"Measured (`bench/results/scaling.json`, {W}×{H}, every mode): {_s(min(host))}–{_s(max(host))} ms of "
            f"Python per render (median), from {pts[0]['elements']:,} to {pts[-1]['elements']:,} elements.")


def scaling_oracle(sc: dict) -> str:
    """docs/scaling.md: the oracle at the largest element count."""
    o = max((r for r in sc["oracle"] if "seconds" in r), key=lambda r: r["elements"])
    small = min((r for r in sc["oracle"] if "seconds" in r), key=lambda r: r["elements"])
    return (f"At {o['elements']:,} elements it renders the {o['size'][0]}×{o['size'][1]} plate in {_s(o['seconds'])} s "
            f"({_ratio(o['seconds'], small['seconds'])} its time at {small['elements']:,}) with a peak of "
            f"{o['peak_rss_mb']:.0f} MB ({machine_line(sc['machine'])}, {sc['date']}).")


def scaling_table(sc: dict) -> str:
    """docs/scaling.md: the element sweep, ratios to riley first."""
    pts = _sc_pts(sc)
    W, H = pts[0]["size"]
    t = lambda r, m: r["renderers"][m]["median_s"]
    lines = [f"Measured on {machine_line(sc['machine'])}, {sc['date']}, at {W}×{H}, median of {sc['reps']} renders "
             "([bench/results/scaling.md](../bench/results/scaling.md)); absolute times vary by machine:", "",
             "| elements | fast / riley | q4 / riley | exact / riley | riley (s) | glsim fast (s) | glsim q4 (s) | "
             "glsim exact (s) | host ms (fast / q4 / exact) |", "|---|---|---|---|---|---|---|---|---|"]
    for r in pts:
        rl = t(r, "riley")
        lines.append(f"| {r['elements']:,} | " + " | ".join(_ratio(t(r, m), rl) for m in ("fast", "q4", "exact"))
                     + f" | {_s(rl)} | " + " | ".join(_s(t(r, m)) for m in ("fast", "q4", "exact")) + " | "
                     + " / ".join(_s(r["renderers"][m]["host_ms"]) for m in ("fast", "q4", "exact")) + " |")
    return "\n".join(lines)


def scaling_passes(sc: dict) -> str:
    """docs/scaling.md: the exact mode's passes over the element sweep."""
    from glsim.evaluation.scaling import PASSES_NOTE, passes_table
    return f"{PASSES_NOTE} One render per element count, after the timed ones:\n\n" + passes_table(sc["elements"], "exact")


def scaling_goals(sc: dict) -> str:
    """docs/scaling.md: issue 19's goals as the run judged them, and what grows with the pixel count."""
    pts = {r["elements"]: r for r in _sc_pts(sc)}
    t = lambda r, m: r["renderers"][m]["median_s"]
    big = [r for n, r in pts.items() if t(r, "exact") < t(r, "riley")]
    lines = ["How the issue's goals fared on this machine (`goals` in scaling.json):", ""]
    for g in sc["goals"]:
        lines.append(f"- **{g['goal']}: {'met' if g['met'] else 'not met' if g['met'] is False else 'not measured'}.** "
                     f"{g['measured']}.")
    if big:
        lines.append(f"- exact takes less time than riley from {min(r['elements'] for r in big):,} elements on ("
                     + ", ".join(_ratio(t(r, 'exact'), t(r, 'riley')) for r in sorted(big, key=lambda r: r['elements']))
                     + "). Below that, the exact mode pays for its per-sample arithmetic: the float64 ray/patch "
                     "intersection, the reference projection and the cubic taps (issue 12).")
    sizes = _sc_pts(sc, "sizes")
    mpx = lambda r: r["size"][0] * r["size"][1] / 1e6
    lines += ["", "The host time grows with the pixel count instead: "
              + ", ".join(f"{_s(max(_host(r)))} ms at {mpx(r):.1f} Mpx" for r in sizes)
              + " (the largest over the modes). Nearly all of it is the saturation statistic (`Result.saturated`), "
              "two or three passes of numpy over the image.", "",
              f"Against image size, at {sizes[0]['elements']:,} elements: fast takes "
              f"{_ratio(min(t(r, 'fast') / t(r, 'riley') for r in sizes), 1)}–"
              f"{_ratio(max(t(r, 'fast') / t(r, 'riley') for r in sizes), 1)} riley's time from {mpx(sizes[0]):.1f} to "
              f"{mpx(sizes[-1]):.1f} Mpx, and exact {_ratio(t(sizes[0], 'exact'), t(sizes[0], 'riley'))} at "
              f"{mpx(sizes[0]):.1f} Mpx and {_ratio(t(sizes[-1], 'exact'), t(sizes[-1], 'riley'))} at {mpx(sizes[-1]):.1f} Mpx."]
    return "\n".join(lines)


# ---- examples/fe_bulge/*.csv: the committed FE solution against linear theory ----------------
FE_PLATE = {"R": 50.0, "t": 3.0, "E": 210000.0, "nu": 0.3, "p": 11.9}     # paper Table 2 (mm, MPa)


def _fe_centre(pressure: float, steps: tuple[list[dict], ...]) -> str:
    pl = FE_PLATE
    D = pl["E"] * pl["t"] ** 3 / (12 * (1 - pl["nu"] ** 2))
    lines = ["| step | p (MPa) | w(0) linear theory (mm) | w(0) FE (mm) | FE / theory − 1 |", "|---|---|---|---|---|"]
    n = len(steps)
    for k, rows in enumerate(steps, 1):
        p = pressure * k / n
        theory = p * pl["R"] ** 4 / (64 * D)
        fe = -float(next(r for r in rows if r["label"].strip() == "1")["uz"])     # node 1: the centre
        lines.append(f"| {k} | {p:.4f} | {theory:.5f} | {fe:.5f} | {100 * (fe / theory - 1):+.3f} % |")
    return "\n".join(lines)


def fe_bulge_centre(*steps: list[dict]) -> str:
    """docs/fe_bulge.md, load case 1: the committed centre deflection at Table 2's pressure in its steps."""
    return _fe_centre(FE_PLATE["p"], steps)


def fe_bulge_centre_5mm(*steps: list[dict]) -> str:
    """docs/fe_bulge.md, load case 2: the pressure at which linear theory reaches 5 mm, in its steps."""
    pl = FE_PLATE
    D = pl["E"] * pl["t"] ** 3 / (12 * (1 - pl["nu"] ** 2))
    return _fe_centre(64 * D * 5.0 / pl["R"] ** 4, steps)


# ---- library.json ------------------------------------------------------------------------------
def library(lib: dict) -> str:
    from glsim.evaluation.library_bench import summary
    return summary(lib)


def preview(pre: dict) -> str:
    """docs/preview.md: the preview's frame times (glsim bench preview)."""
    rows = pre["rows"]
    ms = lambda s: f"{s * 1e3:.0f} ms"
    parts = []
    for r in rows:
        d, f = r["drag_camera"], r["refine"]
        w, h = r["drag_render_size"]
        parts.append(f"{r['case']}: dragging (fast, {w}×{h}) {ms(d['median_s'])} median / {ms(d['p95_s'])} p95 "
                     f"({d['fps_median']:.1f} frames/s), refinement {ms(f['median_s'])} / {ms(f['p95_s'])} "
                     f"(the pair's render {ms(r['refine_render_only']['median_s'])})")
    params = rows[0].get("parameters", {})
    lo = min(params.items(), key=lambda kv: kv[1]["median_s"])
    hi = max(params.items(), key=lambda kv: kv[1]["median_s"])
    g = pre["goals"]
    load = (pre["load_average_before"][0] + pre["load_average_after"][0]) / 2
    return (f"Bulge pair at {pre['size'][0]}×{pre['size'][1]} in a {pre['frame'][0]}×{pre['frame'][1]} frame on "
            f"{machine_line(pre['machine'])} ({pre['date']}; load average about {load:.1f} on its "
            f"{pre['machine']['cores']} cores while it ran):\n\n" + "\n".join(f"- {p}" for p in parts) +
            f"\n\nDragging one parameter takes {ms(lo[1]['median_s'])} ({lo[0]}) to {ms(hi[1]['median_s'])} "
            f"({hi[0]}, which makes a new reference) per frame (median). Goals of issue 11: ≥ {g['drag_fps']:g} frames/s "
            f"dragging at 800×600 — {'met' if g['drag_met'] else 'not met'}; the 1624×1234 refinement within "
            f"{g['refine_s']:g} s — {'met' if g['refine_met'] else 'not met'}.")


def preview_overhead(pre: dict) -> str:
    """docs/preview.md: the preview's own share of a frame (refinement less the pair's render alone)."""
    rows = [r for r in pre["rows"] if "overlays" not in r["case"]]
    own = [1e3 * (r["refine"]["median_s"] - r["refine_render_only"]["median_s"]) for r in rows]
    load = [pre["load_average_before"][0], pre["load_average_after"][0]]
    return (f"The machine these ran on was shared with other work (load average {load[0]:.1f} before and "
            f"{load[1]:.1f} after, on its {pre['machine']['cores']} cores), so the absolute times are inflated; on it "
            f"the preview's own drawing with overlays off (tiles, rig view, info, panel: the refinement frame's median "
            f"less the pair's render alone) takes {min(own):.0f}–{max(own):.0f} ms of a frame, the rest is the renderer.")


# ---- quadratic.json ----------------------------------------------------------------------------
def quadratic_tables(q: dict) -> str:
    """Both meshes' tables (glsim bench quadratic), with the run's conditions."""
    from glsim.evaluation.quadratic import markdown
    body = markdown(q).split("\n", 2)[2]          # without the page title
    return body


def quadratic_rows(q: dict) -> str:
    """The Q8 rows of the accuracy table: GL and oracle per mode, mapping error and time."""
    from glsim.evaluation.quadratic import mode_label
    m = next(x for x in q["meshes"] if x["kind"] == "quad8")
    exact = next(r["time"] for r in m["rows"] if r["backend"] == "gl" and r["mode"] == "exact")
    lines = [f"Q8 elements (`glsim bench quadratic`: a paraboloid of {m['elements']} Q8 elements of about "
             f"{m['element_px']:.0f} px, against its closed form, {q['size'][0]}×{q['size'][1]} px, 1 spp; "
             f"{machine_line(q['machine'])}, {q['date']}):", "",
             "| backend | mode | mapping error mean / max (ref px) | time / GL exact | time (s) |", "|---|---|---|---|---|"]
    lines += [f"| {r['backend']} | {mode_label(r)} | {_s(r['map_mean'])} / {_s(r['map_max'])} | {_s(r['time'] / exact)} | "
              f"{_s(r['time'])} |" for r in m["rows"]]
    return "\n".join(lines)


def quadratic_fast(q: dict) -> str:
    """The fast mode's error against its piece count (the 1/n² law)."""
    m = next(x for x in q["meshes"] if x["kind"] == "quad8")
    fast = sorted((r for r in m["rows"] if r["backend"] == "gl" and r["mode"] == "fast"), key=lambda r: r["pieces"])
    steps = " → ".join(_s(r["map_mean"]) for r in fast)
    ns = ", ".join(str(r["pieces"]) for r in fast)
    ratios = ", ".join(_s(a["map_mean"] / b["map_mean"]) for a, b in zip(fast, fast[1:]))
    return (f"The fast mode's error is the chord error of the pieces: on Q8 it goes {steps} px mean for n = {ns} "
            f"pieces per side (each halving of the piece size divides it by {ratios}; 1/n² gives 4).")


def check_drivers(*reports: dict) -> str:
    """README: the drivers `glsim check` was run on (bench/results/check-*.json), check by check."""
    names = [r["name"] for r in reports[0]["checks"]]
    lines = ["| check | bound | " + " | ".join(machine_line(r["machine"]) + f", {r['date']}, {_s(r['seconds'])} s" for r in reports) + " |",
             "|---|---|" + "---|" * len(reports)]
    for k, name in enumerate(names):
        row = reports[0]["checks"][k]
        cells = []
        for r in reports:
            c = r["checks"][k]
            cells.append("skipped" if c["passed"] is None else
                         f"{_s(c['value'])} {'✓' if c['passed'] else '**✗**'}")
        lines.append(f"| {name} | {_s(row['bound'])} {row['unit']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


GENERATORS = {"check-drivers": check_drivers, "preview": preview, "accuracy-table": accuracy_table, "accuracy-facts": accuracy_facts, "peer": peer,
              "effects": effects, "effects-dof": effects_dof, "effects-dof-facts": effects_dof_facts, "verify-table": verify_table,
              "verify-runs-table": verify_runs_table, "sweep-table": sweep_table, "sweep": sweep, "calibration": calibration,
              "calibration-detection": calibration_detection, "calibration-accuracy": calibration_accuracy,
              "calibration-targets": calibration_targets, "calibration-estimators": calibration_estimators, "library": library,
              "calibration-resolution": calibration_resolution, "calibration-estimator-facts": calibration_estimator_facts,
              "calibration-spread-facts": calibration_spread_facts, "calibration-corner-facts": calibration_corner_facts,
              "calibration-timing": calibration_timing, "calibration-study": calibration_study,
              "verify-scale": verify_scale, "verify-choices": verify_choices, "verify-facts": verify_facts,
              "verify-timing": verify_timing, "sweep-facts": sweep_facts, "sweep-frontier": sweep_frontier,
              "sweep-timing": sweep_timing, "scaling-host": scaling_host, "scaling-oracle": scaling_oracle,
              "scaling-table": scaling_table, "scaling-goals": scaling_goals, "scaling-passes": scaling_passes,
              "preview-overhead": preview_overhead, "fe-bulge-centre": fe_bulge_centre,
              "fe-bulge-centre-5mm": fe_bulge_centre_5mm, "sweep-subsets": sweep_subsets,
              "quadratic-tables": quadratic_tables, "quadratic-rows": quadratic_rows, "quadratic-fast": quadratic_fast,
              "peer-rows": peer_rows}


# ---- regions ---------------------------------------------------------------------------------
def render_region(name: str, sources: list[str], root: Path) -> str:
    """The body of one generated region (ending in a newline)."""
    if name not in GENERATORS:
        raise GlsimError(f"generated region {name!r}: unknown; use one of {', '.join(GENERATORS)}")
    data = []
    for s in sources:
        path = root / s
        if not path.is_file():
            raise GlsimError(f"generated region {name!r}: results file {s} not found — run the benchmark that writes it")
        if s.endswith(".csv"):                   # a table of rows: a calibration study's, an FE step's (label;ux;uy;uz)
            with open(path, newline="") as f:
                first = f.readline()
                f.seek(0)
                data.append(list(csv.DictReader(f, delimiter=";" if ";" in first and "," not in first else ",")))
        else:
            data.append(json.loads(path.read_text()))
    return GENERATORS[name](*data).rstrip("\n") + "\n"


def regenerate(text: str, root: Path) -> str:
    """``text`` with every generated region's body made anew from its results files."""
    def sub(m):
        sources = [s.strip() for s in m["sources"].split(",")]
        return m.group(1) + render_region(m["name"], sources, root) + m.group(5)
    return REGION.sub(sub, text)


def check(root: Path, files=FILES) -> list[str]:
    """A diff per file whose generated regions differ from their results files (empty: all agree)."""
    out = []
    for f in files:
        path = root / f
        if not path.is_file():
            continue
        text = path.read_text()
        new = regenerate(text, root)
        if new != text:
            out.append("".join(difflib.unified_diff(text.splitlines(True), new.splitlines(True), f, f + " (generated)")))
    return out


def write(root: Path, files=FILES) -> list[str]:
    """Rewrite the generated regions in place; the files that changed."""
    changed = []
    for f in files:
        path = root / f
        if path.is_file() and (new := regenerate(text := path.read_text(), root)) != text:
            io.write_text(path, new)
            changed.append(f)
    return changed
