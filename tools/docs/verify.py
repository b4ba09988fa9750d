"""Generators of verify.json, sweep.json and sweep_backends.json: the README's and
docs/verify.md's DIC verification figures."""
from __future__ import annotations

from glsim.bench.formatting import ratio, sig
from glsim.bench.report import machine_line
from tools.docs.accuracy import record


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
            lines.append(f"| {sq['label']} | {rq['dir']} | {sig(rq['mean_px'])} / {sig(rq['std_px'])} | "
                         f"{sig(ra['mean_px'])} / {sig(ra['std_px'])} | {sig(paper[0], 3)} / {sig(paper[1], 3)} |")
    return "\n".join(lines)


def verify_runs_table(ver: dict) -> str:
    """Every DIC run side by side (bold: outside the goal), the paper's figures, subsets compared."""
    goal, runs = ver["goal_px"], ver["runs"]

    def cell(x, limit):
        return f"**{sig(x)}**" if abs(x) > limit else sig(x)
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
                         + (f"{sig(paper[0], 3)} | {sig(paper[1], 3)}" if paper else "– | –") + " |")
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
            f"reference-state Z std from {sig(_vrow(a, 'undeformed', 'Z')['std_px'])} to "
            f"{sig(_vrow(a8, 'undeformed', 'Z')['std_px'])} px and the Y std from {sig(_vrow(a, 'undeformed', 'Y')['std_px'])} "
            f"to {sig(_vrow(a8, 'undeformed', 'Y')['std_px'])} px (table3 vs table3-8bit); with the quadratic shape function "
            f"the reference-state Z std is {sig(_vrow(q, 'undeformed', 'Z')['std_px'])} px and the deformed-state Z std "
            f"{sig(_vrow(q, 'deformed', 'Z')['std_px'])} px; {left} of its {q['n_subsets']} subsets "
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
        ([f"mean {sig(r['mean_px'])}"] if abs(r["mean_px"]) > goal["mean"] else [])
        + ([f"std {sig(r['std_px'])}"] if r["std_px"] > goal["std"] else [])) for lab, r in miss)
    return "\n".join([
        f"- With the **quadratic** shape function every row meets the goal: |means| ≤ "
        f"{sig(max(abs(r['mean_px']) for r in every))} px, stds ≤ {sig(max(r['std_px'] for r in every))} px; the stds "
        f"of X, Y, Z are {min(ratios):.0f} to {max(ratios):.0f} times below the paper's.",
        f"- With the paper's **affine** shape function (Table 3) these miss the goal (px): {what}."])


def verify_timing(ver: dict) -> str:
    """docs/verify.md: render and DIC times of the run, the DIC relative to the render."""
    r = ver["render_seconds"]
    return (f"Same run ({machine_line(ver['machine'])}, {ver['date'][:10]}): the DIC takes "
            + ", ".join(f"{ratio(x['dic_seconds'], r)} ({x['name']})" for x in ver["runs"])
            + f" the time of rendering the four images and the truth maps ({sig(r)} s; DIC "
            + ", ".join(f"{sig(x['dic_seconds'])} s" for x in ver["runs"]) + ").")


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
    mp = {m: record(acc, "gl", m, "bspline3", 1)["map_rms_px"] for m in ("fast", "q4")}
    return "\n".join([
        f"- **The DIC's own S-curve** (pyvale on the exact model images): ±{sig(model['max_abs_bias_u'])} px, "
        + (f"zero at {rows[0]['shift_px']:g} and {rows[-1]['shift_px']:g} px" if ends == [0, 0] else
           f"{sig(ends[0])} and {sig(ends[1])} at {rows[0]['shift_px']:g} and {rows[-1]['shift_px']:g} px") + " and "
        + f"{sig(half['bias_u'])} px at 0.5 px, {'negative' if below else 'not always negative'} below 0.5 px at 1 spp; "
        f"the std peaks at {peak['shift_px']:g} px ({sig(peak['std_u'])} px with {model['subset_size']}-px subsets, "
        f"{sig(by['model', s1]['max_std_u'])} with {by['model', s1]['subset_size']}). At 4 spp the bias is "
        f"±{sig(m4['max_abs_bias_u'])} px, the largest std {sig(m4['max_std_u'])} px: most of the DIC's error on this "
        "speckle comes from its 1-px dot edges aliasing at 1 spp. The subset size changes the std, not the bias.",
        f"- **exact/procedural has no generator bias**: its images equal the model images (grey RMS "
        f"{sig(255 * proc['max_grey_rms_vs_model'])} of an 8-bit level, float32 evaluation in the shader; the CPU oracle "
        f"matches to 2 float32 ulp, `tests/test_sweep.py`), pyvale reads them within {sig(proc['max_abs_gen_u'])} px of "
        f"the model, and the generator-alone shift error is {sig(min(app))} to {sig(max(app))} px at every shift "
        "(float32 reference coordinates in GL).",
        f"- **bspline3 interpolation displaces the speckle**: the generator-alone error reaches "
        f"±{sig(bsp['max_abs_apparent_u'])} px (zero where the reference coordinates are whole pixels of the "
        f"2×-oversampled reference image: {', '.join(f'{z:g}' for z in zero)} px), ±{sig(bsp4['max_abs_apparent_u'])} px "
        f"at 4 spp; it is a {sig(255 * bsp['max_grey_rms_vs_model'])}-level (8-bit) RMS grey error. pyvale, which "
        f"compares the images only with each other, reads up to {sig(bsp['max_abs_gen_u'])} px of it "
        f"({sig(bsp4['max_abs_gen_u'])} px at 4 spp), the size of `glsim verify`'s 1e-3 px goal. (This is the "
        "unfiltered speckle, the hardest case; `glsim verify`'s σ = 1 px low-passed reference has much less content "
        "near the reference's Nyquist frequency.)",
        "- **The modes are not separated by this sweep**: a plate square to a distortion-free camera projects "
        f"affinely, which `fast` and `q4` reproduce exactly; their DIC bias curves coincide with `exact`'s to "
        f"{sig(coincide)} px. Their mapping errors ({sig(mp['fast'])} and {sig(mp['q4'])} px RMS on the bulge, "
        "`accuracy.json`) appear only with perspective, curvature or distortion."])


def sweep_frontier(acc: dict, sw: dict) -> str:
    """docs/verify.md: the frontier's ends and which default the data support (accuracy.json, sweep.json)."""
    ex, q4 = record(acc, "gl", "exact", "bspline3", 1), record(acc, "gl", "q4", "bspline3", 1)
    fast = min((r for r in acc["records"] if r["backend"] == "gl" and r["mode"] == "fast" and r["spp"] == 1
                and r["precision"] == "fp64"), key=lambda r: r["seconds"])
    proc = record(acc, "gl", "exact", "procedural", 1)
    spp = max(r["spp"] for r in acc["records"])
    b16 = record(acc, "gl", "exact", "bspline3", spp)
    by = {(r["sequence"], r["run"]): r for r in sw["results"]}
    s0 = sw["runs"][0]["name"]
    bsp, p512, b512 = by["exact-bspline3", s0], by["exact-procedural", s0], by["exact-bspline3", s0]
    approx = [r for r in acc["records"] if r["backend"] == "gl" and r["mode"] in ("fast", "q4")]
    lo, hi = min(r["map_rms_px"] for r in approx), max(r["map_max_px"] for r in approx)
    W, H = acc["size"]
    return (f"From `accuracy.json` ({machine_line(acc['machine'])}, {acc['date'][:10]}): the mapping front is `fast` "
            f"({sig(fast['seconds'])} s, {sig(fast['map_rms_px'])} px RMS) then `exact` ({sig(ex['seconds'])} s, "
            f"{sig(ex['map_rms_px'])} px); the grey front ends in `exact`/`procedural` ({sig(proc['seconds'])} s, "
            f"{sig(proc['speckle_rms'])} levels at 1 spp), which `bspline3` does not approach even at {spp} spp "
            f"({sig(b16['speckle_rms'])} levels, {sig(b16['seconds'])} s).\n\n"
            f"**Which default the data support**: mode `exact` — `fast` and `q4` take {ratio(fast['seconds'], ex['seconds'])} "
            f"and {ratio(q4['seconds'], ex['seconds'])} its time but misplace the speckle by {lo / 1e-3:.0f} (RMS) to "
            f"{hi / 1e-3:.0f} (max) times the 1e-3 px a sub-pixel DIC check needs. For the interpolation, `procedural` "
            f"whenever the reference is the built-in generator: it removes a generator bias of up to "
            f"{sig(bsp['max_abs_apparent_u'])} px ({sig(bsp['max_abs_gen_u'])} px as pyvale reads it) for "
            f"{ratio(proc['seconds'], ex['seconds'])} the time of `bspline3` ({sig(proc['seconds'])} against "
            f"{sig(ex['seconds'])} s per {W}×{H} image; {ratio(p512['render_seconds_median'], b512['render_seconds_median'])}, "
            f"{sig(p512['render_seconds_median'])} against {sig(b512['render_seconds_median'])} s at "
            f"{sw['size'][0]}×{sw['size'][1]} in the sweep).")


def sweep_timing(sw: dict) -> str:
    """docs/verify.md: where the sweep's time goes."""
    dic = [r["dic_seconds"] for r in sw["results"]]
    t = sw["seconds"]
    return (f"**Timings** ({machine_line(sw['machine'])}, {sw['date'][:10]}): rendering the images, the model images "
            f"and the files {sig(t['render_and_write'])} s, generator-alone fits {sig(t['apparent_shift'])} s, pyvale "
            f"{sig(sum(dic))} s ({len(dic)} calls of {sig(min(dic))}–{sig(max(dic))} s).")


# ---- sweep.json, sweep_backends.json ---------------------------------------------------------
def sweep(sw: dict, backends: dict) -> str:
    by = {(r["sequence"], r["run"]): r for r in sw["results"]}
    run = sw["runs"][0]["name"]
    model, proc, bsp = by["model", run], by["exact-procedural", run], by["exact-bspline3", run]
    noise = [r["max_std_u"] for r in sw["results"] if r["source"] == "model"]
    exact_rows = [r for r in backends["rows"] if r["sequence"].startswith("exact")]
    return (f"The DIC's own S-curve on the exactly shifted model images is ±{sig(model['max_abs_bias_u'])} px at one "
            f"sample per pixel (subset {model['subset_size']} px). `exact` with the procedural speckle adds "
            f"{sig(proc['max_abs_gen_u'])} px to it; B-spline interpolation of the generated reference moves the speckle "
            f"by up to {sig(bsp['max_abs_apparent_u'])} px (zero at whole and half pixels), of which the DIC sees "
            f"{sig(bsp['max_abs_gen_u'])} px. The same sweep rendered by the CPU oracle differs from GL by at most "
            f"{sig(max(r['max_delta_bias_px'] for r in backends['rows']))} px in bias "
            f"({sig(max(r['max_delta_bias_px'] for r in exact_rows))} px in exact mode), against the DIC's own scatter "
            f"of {sig(min(noise))}–{sig(max(noise))} px.")


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
        render = (f"(numpy {sig(first['render_seconds_median'])})" if first["source"] == "model"
                  else sig(first["render_seconds_median"]))
        lines.append(f"| {s} | {render} | {' / '.join(sig(r['max_abs_bias_u']) for r in rs)} | "
                     f"{' / '.join(sig(r['max_std_u']) for r in rs)} | {sig(first['max_abs_gen_u'])} | "
                     f"{sig(first['max_abs_apparent_u'])} |")
    return "\n".join(lines)
