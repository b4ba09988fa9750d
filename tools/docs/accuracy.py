"""Generators of accuracy.json, peer.json and effects.json: the README's accuracy,
peer and effects figures, docs/effects.md's depth of field."""
from __future__ import annotations

from glsim.errors import GlsimError
from glsim.bench.formatting import ratio, sig
from glsim.bench.report import machine_line


# ---- accuracy.json ---------------------------------------------------------------------------
EXCERPT = (("gl", "fast", "linear", 1, "fp64"), ("gl", "fast", "bspline3", 1, "fp64"),
           ("gl", "q4", "bspline3", 1, "fp64"), ("gl", "q4", "bspline3", 1, "fp32"), ("gl", "exact", "bspline3", 1, "fp64"),
           ("gl", "exact", "bspline3", 4, "fp64"), ("gl", "exact", "bspline3", 4, "fp64", "newton"),
           ("gl", "exact", "bspline3", 1, "fp32"),
           ("gl", "exact", "procedural", 1, "fp64"), ("gl", "exact", "procedural", 4, "fp64"),
           ("cpu", "exact", "bspline3", 1, "fp64"))


def record(acc: dict, backend: str, mode: str, interp: str, spp: int, precision: str = "fp64",
            subsamples: str = "mapped") -> dict:
    for r in acc["records"]:
        if (r["backend"], r["mode"], r["interpolation"], r["spp"], r["precision"], r.get("subsamples", "mapped")) \
                == (backend, mode, interp, spp, precision, subsamples):
            return r
    raise GlsimError(f"accuracy.json has no row {backend} {mode} {interp} {spp} spp {precision} {subsamples}: "
                     "run `glsim bench accuracy` at full size")


def accuracy_table(acc: dict) -> str:
    base = record(acc, "gl", "exact", "bspline3", 1)
    lines = [f"Bulge, camera 0 at the full bulge, {acc['size'][0]}×{acc['size'][1]}; time relative to GL exact "
             f"fp64 bspline3 at 1 spp in the same run, then the median per image on {machine_line(acc['machine'])} "
             f"({acc['date'][:10]}); mapping error in reference-image px against the float64 exact oracle; grey "
             "error in 8-bit grey levels against the exact speckle.", "",
             "| backend | mode | arithmetic | interpolation | spp | time ratio | time (s) | mapping RMS / max (px) "
             "| grey RMS vs exact speckle |", "|---|---|---|---|---|---|---|---|---|"]
    for key in EXCERPT:
        r = record(acc, *key)
        mode = ("exact (oracle)" if r["backend"] == "cpu" else "q4 (paper)" if r["mode"] == "q4"
                else "exact, newton sub-samples" if r.get("subsamples") == "newton" else r["mode"])
        mapping = "0" if r["map_max_px"] == 0 else f"{sig(r['map_rms_px'])} / {sig(r['map_max_px'])}"
        lines.append(f"| {r['backend']} | {mode} | {r['arithmetic']} | {r['interpolation']} | {r['spp']} | "
                     f"{ratio(r['seconds'], base['seconds'])} | {sig(r['seconds'])} | {mapping} | "
                     f"{sig(r['speckle_rms'])} |")
    return "\n".join(lines)


def accuracy_facts(acc: dict) -> str:
    ex, ex32 = record(acc, "gl", "exact", "bspline3", 1), record(acc, "gl", "exact", "bspline3", 1, "fp32")
    gl = [r for r in acc["records"] if r["backend"] == "gl" and r["precision"] == "fp64"]
    approx = [r for r in gl if r["mode"] in ("fast", "q4")]
    grey1 = [r["speckle_rms"] for r in gl if r["spp"] == 1 and r["interpolation"] != "procedural"]
    cpu = {(r["mode"], r["interpolation"]): r["seconds"] for r in acc["records"] if r["backend"] == "cpu" and r["spp"] == 1}
    speedups = [cpu[m, i] / record(acc, "gl", m, i, 1)["seconds"] for m, i in cpu]
    fast = {r["interpolation"]: r["seconds"] / ex["seconds"] for r in gl if r["mode"] == "fast" and r["spp"] == 1}
    q4 = record(acc, "gl", "q4", "bspline3", 1)
    return "\n".join([
        f"- GL `exact` (fp64) maps every pixel within {sig(max(r['map_max_px'] for r in gl if r['mode'] == 'exact'))} px "
        "of the float64 oracle; its fp32 variant errs by up to "
        f"{sig(ex32['map_max_px'])} px and takes {ratio(ex32['seconds'], ex['seconds'])} the fp64 time.",
        f"- `fast` and the paper's `q4` misplace the speckle by up to {sig(max(r['map_max_px'] for r in approx))} px "
        f"(RMS {sig(min(r['map_rms_px'] for r in approx))}–{sig(max(r['map_rms_px'] for r in approx))} px); at 1 spp "
        f"`q4` takes {ratio(q4['seconds'], ex['seconds'])} and `fast` "
        f"{ratio(min(fast.values()), 1)}–{ratio(max(fast.values()), 1)} the time of `exact`.",
        f"- Texture interpolation of the generated speckle leaves {sig(min(grey1))}–{sig(max(grey1))} grey levels RMS "
        "at 1 spp; the procedural speckle "
        f"{sig(record(acc, 'gl', 'exact', 'procedural', 1)['speckle_rms'])}.",
        f"- The GL path is {ratio(min(speedups), 1)}–{ratio(max(speedups), 1)} faster than the numpy oracle at 1 spp "
        "(same modes and interpolations).",
        *[f"- At {spp} spp (bspline3), sub-samples placed by Newton from the pixel centre (`subsamples = \"newton\"`) take "
          f"{ratio(nw['seconds'], mp['seconds'])} the time of sub-samples each mapped on its ray; grey error against the "
          f"oracle's image: max {sig(nw['grey_max'])} grey levels (mapped: {sig(mp['grey_max'])})."
          for spp in sorted({r["spp"] for r in gl if r.get("subsamples") == "newton"})
          for nw, mp in [(record(acc, "gl", "exact", "bspline3", spp, "fp64", "newton"),
                          record(acc, "gl", "exact", "bspline3", spp))]],
    ])


def peer(acc: dict) -> str:
    p = {x["name"].split()[0] if x["name"].startswith("riley") else x["name"]: x for x in acc["peer"]}
    riley, q4, ex = p.get("riley-raster"), p.get("glsim GL q4 fp64"), p.get("glsim GL exact fp64")
    if not (riley and q4 and ex) or "ok" != riley["status"]:
        return "riley-raster was not installed in the run that wrote accuracy.json."
    name = next(x["name"] for x in acc["peer"] if x["name"].startswith("riley"))
    return (f"Peer, same run, interleaved ({machine_line(acc['machine'])}): glsim GL takes "
            f"{ratio(q4['seconds'], riley['seconds'])} the time of {name} (pyvale's SIMD CPU rasteriser) in q4 mode and "
            f"{ratio(ex['seconds'], riley['seconds'])} in exact mode, on a face-on plate covering "
            f"{riley['coverage']:.0%} of the image, cubic interpolation, 4 spp ({sig(riley['seconds'])} s, "
            f"{sig(q4['seconds'])} s, {sig(ex['seconds'])} s).")


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
    lines += [f"| {r['renderer']} | {r['k1']:g} | {sig(r['glsim_over_riley'])} | {sig(r['riley_over_glsim'])} | "
              f"{sig(r['seconds'])} | {sig(r['map_rms_px'])} / {sig(r['map_max_px'])} | {sig(r['grey_rms'])} |" for r in ok]
    lines += ["", "The peer goals in that run:", "", "| goal | measured | met |", "|---|---|---|"]
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
            f"effect-free image, all three {ratio(g('all'), g('none'))} its time; the CPU oracle takes "
            f"{ratio(c('none'), g('none'))} GL's time without effects and {ratio(c('all'), g('all'))} with all. "
            f"Absolute: GL {sig(g('none'))} s and {sig(g('all'))} s per image, CPU {sig(c('none'))} s and {sig(c('all'))} s "
            f"({machine_line(eff['machine'])}, {eff['date'][:10]}).")


def effects_camera(eff: dict) -> str:
    """docs/camera.md: the camera-effect rows (lens PSF, vignetting, fill factor, fixed pattern)."""
    from glsim.bench.effects import camera_table
    if not eff.get("camera"):
        return "(no camera rows in this results file: run `glsim bench effects --only camera`)"
    run = eff.get("camera_run", eff)
    return camera_table(eff["camera"]) + f"\n\n{machine_line(run['machine'])}, {run['date'][:10]}."


def effects_motion(eff: dict) -> str:
    """docs/motion.md: the motion rows (exposure, rolling shutter, rolling shutter with a PSF)."""
    from glsim.bench.effects import motion_table
    if not eff.get("motion"):
        return "(no motion rows in this results file: run `glsim bench effects --only motion`)"
    run = eff.get("motion_run", eff)
    return motion_table(eff) + f"\n\n{machine_line(run['machine'])}, {run['date'][:10]}; {eff['size'][0]} × {eff['size'][1]} px."


def effects_dof(eff: dict) -> str:
    """docs/effects.md: every GL depth-of-field scheme against the oracle's exact 2-D gather."""
    from glsim.bench.effects import dof_table
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
            f"errs by at most {sig(default)} of full scale ({sig(255 * default)} grey levels of 8 bit; goal {sig(goal)}), "
            f"`gather` and `hybrid` by {sig(exact)}; the separable pair by up to {sig(max(r['max_error'] for r in sep))} "
            f"({sum(r['over_goal'] for r in sep)} pixels beyond the goal). Time per image with depth of field only, "
            f"relative to the separable pair in the same run: bulge at {eff['size'][0]}×{eff['size'][1]} "
            f"(σ {sig(blur['bulge'][0])}–{sig(blur['bulge'][1])} px) expansion {ratio(bulge['expansion']['seconds'], bulge['separable']['seconds'])}, gather "
            f"{ratio(bulge['gather']['seconds'], bulge['separable']['seconds'])}, hybrid "
            f"{ratio(bulge['hybrid']['seconds'], bulge['separable']['seconds'])}; hole at {size[0]}×{size[1]} "
            f"(σ {sig(blur['hole'][0])}–{sig(blur['hole'][1])} px) {ratio(t['expansion'], t['separable'])}, {ratio(t['gather'], t['separable'])} and "
            f"{ratio(t['hybrid'], t['separable'])} ({machine_line(eff['machine'])}, {eff['date'][:10]}).")
