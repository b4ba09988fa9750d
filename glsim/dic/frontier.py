"""The accuracy–time frontier: error versus time per image for every row of
``bench/results/accuracy.json`` (mapping RMS and grey RMS against the exact speckle), with the
rigid-body sweep's DIC-measured bias for the sequences it ran (``glsim verify frontier``)."""
from __future__ import annotations

import math
from pathlib import Path

from glsim.workflows.figures import save_figure
from glsim.dic.sweep import results_by_sequence, sequence_style


INTERP_COLOURS = {"linear": "tab:gray", "cubic": "tab:orange", "bspline3": "tab:blue",
                  "bspline5": "tab:purple", "procedural": "tab:green"}


MODE_MARKERS = {"fast": "o", "q4": "s", "exact": "^"}


FLOOR = {"map": 1e-13, "grey": 1e-4}      # where 0 is drawn on the log axes


def _label(rec: dict) -> str:
    arith = rec.get("arithmetic", rec.get("precision", ""))
    return f"{rec['backend']} {rec['mode']} {arith} {rec['interpolation']} {rec['spp']}spp"


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats in both coordinates (smaller is better),
    sorted by the first coordinate."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], math.inf
    for i in order:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def accuracy_lookup(accuracy: dict, backend: str, mode: str, interpolation: str, spp: int,
                    arithmetic: str | None = None) -> dict | None:
    """The accuracy.json record of a configuration (GL: fp64 precision unless ``arithmetic``)."""
    for rec in accuracy["records"]:
        if (rec["backend"], rec["mode"], rec["interpolation"], rec["spp"]) == (backend, mode, interpolation, spp) \
                and rec.get("subsamples", "mapped") == "mapped" \
                and (rec.get("precision", "fp64") == "fp64" if arithmetic is None else rec.get("arithmetic") == arithmetic):
            return rec
    return None


def plot_frontier(accuracy: dict, sweep: dict | None, path: str | Path) -> Path:
    """Log–log error versus time per image: mapping RMS and grey RMS against the exact speckle
    for every accuracy.json row (colour: interpolation, marker: mode, size: spp, hollow: CPU,
    thin: GL fp32), the Pareto front of each; with ``sweep``, the DIC-measured max |bias| and
    max |generator bias| of its sequences at the time accuracy.json gives their configuration."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    panels = [("map_rms_px", "mapping RMS |ref_uv − exact| (reference px)", "map"),
              ("speckle_rms", "grey RMS vs exact speckle (8-bit grey levels)", "grey")]
    n = len(panels) + (sweep is not None)
    fig, axes = plt.subplots(1, n, figsize=(6.2 * n, 5.6), squeeze=False)
    axes = axes[0]
    recs = accuracy["records"]
    for ax, (key, ylabel, floor) in zip(axes, panels):
        pts = [(rec["seconds"], max(rec[key], FLOOR[floor])) for rec in recs]
        for rec, (x, y) in zip(recs, pts):
            c = INTERP_COLOURS.get(rec["interpolation"], "k")
            cpu = rec["backend"] == "cpu"
            fp32 = rec["backend"] == "gl" and rec.get("precision") == "fp32"
            ax.scatter([x], [y], s=18 + 5 * rec["spp"], marker=MODE_MARKERS.get(rec["mode"], "d"),
                       facecolors="none" if cpu else c, edgecolors=c, linewidths=0.6 if fp32 else 1.2,
                       alpha=0.45 if fp32 else 0.9)
        # Rows whose error is exactly 0 are the reference itself (CPU exact for the mapping): drawn
        # at the floor, left out of the front.
        cand = [i for i, rec in enumerate(recs) if rec[key] > 0]
        front = [cand[i] for i in pareto([pts[i] for i in cand])]
        ax.plot([pts[i][0] for i in front], [pts[i][1] for i in front], color="k", lw=0.8, alpha=0.6,
                label="Pareto front")
        default = accuracy_lookup(accuracy, "gl", "exact", "bspline3", 1)
        if default:
            ax.annotate("default\n(exact, bspline3, 1 spp)", (default["seconds"], max(default[key], FLOOR[floor])),
                        xytext=(12, -24), textcoords="offset points", fontsize=7, arrowprops={"arrowstyle": "->", "lw": 0.6})
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time per image (s), " + f"{accuracy['size'][0]}×{accuracy['size'][1]}")
        ax.set_ylabel(ylabel + f" (0 drawn at {FLOOR[floor]:.0e})")
        ax.grid(True, which="both", alpha=0.25)
    handles = ([Line2D([], [], color=c, marker="o", ls="", label=i) for i, c in INTERP_COLOURS.items()]
               + [Line2D([], [], color="k", marker=m, ls="", mfc="none", label=md) for md, m in MODE_MARKERS.items()]
               + [Line2D([], [], color="k", lw=0.8, label="Pareto front")])
    axes[0].legend(handles=handles, fontsize=7, loc="center left", title="size ∝ spp; hollow: CPU",
                   title_fontsize=7)
    if sweep is not None:
        ax = axes[-1]
        run = sweep["runs"][0]["name"]
        seq_handles = []
        for r in sweep["results"]:
            if r["run"] != run:
                continue
            c, m, _ = sequence_style(r["sequence"])
            if r["source"] == "model":
                ax.axhline(r["max_abs_bias_u"], color=c, ls="--", lw=0.8)
                seq_handles.append(Line2D([], [], color=c, ls="--", lw=0.8,
                                          label=f"{r['sequence']}: the DIC's own max |bias| {r['max_abs_bias_u']:.1e}"))
                continue
            rec = accuracy_lookup(accuracy, "gl", r["mode"], r["interpolation"], r["spp"])
            if rec is None:
                continue
            x = rec["seconds"] * (1.0 + 0.04 * ("q4" in r["sequence"]))   # q4 and exact overlap otherwise
            ax.scatter([x], [r["max_abs_bias_u"]], color=c, marker=m, s=40)
            if r.get("max_abs_gen_u") is not None:
                ax.scatter([x], [max(r["max_abs_gen_u"], 1e-8)], color=c, marker=m, s=14, alpha=0.7)
            if r.get("max_abs_apparent_u") is not None:
                ax.scatter([x], [max(r["max_abs_apparent_u"], 1e-8)], facecolors="none", edgecolors=c, marker=m, s=60)
            seq_handles.append(Line2D([], [], color=c, marker=m, ls="", label=r["sequence"]))
        kinds = [Line2D([], [], color="k", marker="o", ls="", ms=7, label="DIC max |u − shift| (bias)"),
                 Line2D([], [], color="k", marker="o", ls="", ms=4, alpha=0.7, label="DIC max |u − u_model| (generator share)"),
                 Line2D([], [], color="k", marker="o", ls="", ms=8, mfc="none", label="max |apparent shift error| (generator, no DIC)")]
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"time per image (s), {accuracy['size'][0]}×{accuracy['size'][1]} (accuracy.json)")
        ax.set_ylabel("error over the rigid sweep 0…1 px (px)")
        ax.set_title(f"rigid sweep (plate square to the camera), pyvale subset {sweep['runs'][0]['subset_size']} px",
                     fontsize=9)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(handles=seq_handles + kinds, fontsize=6, loc="lower left")
    fig.suptitle(f"glsim accuracy versus time ({accuracy['machine']['gl']['renderer']}, "
                 f"{accuracy['machine']['cores']} cores)", fontsize=10)
    return save_figure(fig, path, dpi=110)


def frontier_facts(accuracy: dict, sweep: dict | None) -> dict:
    """The numbers the default-mode paragraph quotes: accuracy.json rows (bulge, GL fp64) and
    the sweep's amplitudes (first run)."""
    f = {}
    for mode in ("fast", "q4", "exact"):
        for interp in ("bspline3", "procedural"):
            for spp in (1, 4, 16):
                rec = accuracy_lookup(accuracy, "gl", mode, interp, spp)
                if rec:
                    f[(mode, interp, spp)] = rec
    if sweep is not None:
        f["sweep"] = results_by_sequence(sweep)
    return f


def frontier_markdown(accuracy: dict, sweep: dict | None) -> list[str]:
    """The frontier section: the Pareto rows of each error measure, and which default the data support."""
    lines = ["## Frontier (`frontier.png`)", "",
             f"From `accuracy.json` ({accuracy['scene']}, {accuracy['size'][0]}×{accuracy['size'][1]}, "
             f"{accuracy['date']}): error versus median time per image. Pareto-optimal rows (no other row is "
             "both faster and more accurate; error 0 marks the reference itself and is left out):", ""]
    recs = accuracy["records"]
    for key, name, floor in (("map_rms_px", "mapping RMS (px)", "map"),
                             ("speckle_rms", "grey RMS vs exact speckle (8-bit levels)", "grey")):
        cand = [i for i, r in enumerate(recs) if r[key] > 0]
        pts = [(recs[i]["seconds"], recs[i][key]) for i in cand]
        lines += [f"| {name}: row | time (s) | error |", "|---|---|---|"]
        for j in pareto(pts):
            r = recs[cand[j]]
            lines.append(f"| {_label(r)} | {r['seconds']:.3g} | {r[key]:.3g} |")
        lines.append("")
    f = frontier_facts(accuracy, sweep)
    lines += ["## Which default the data support", ""]
    eb, fb, qb = f.get(("exact", "bspline3", 1)), f.get(("fast", "bspline3", 1)), f.get(("q4", "bspline3", 1))
    ep, ep4 = f.get(("exact", "procedural", 1)), f.get(("exact", "procedural", 4))
    sw = f.get("sweep")
    if eb and fb and qb:
        lines.append(
            f"- **Mode: `exact`.** On the bulge, GL `exact` maps every pixel to within {eb['map_max_px']:.0e} px "
            f"({eb['seconds']:.3f} s per 1624×1234 image with bspline3); `fast` is {eb['seconds'] / fb['seconds']:.1f}× "
            f"and `q4` {eb['seconds'] / qb['seconds']:.1f}× faster but misplace the speckle by "
            f"{fb['map_rms_px']:.3f} px RMS ({fb['map_max_px']:.2f} max) and {qb['map_rms_px']:.3f} px RMS "
            f"({qb['map_max_px']:.2f} max): {min(fb['map_rms_px'], qb['map_rms_px']) / 1e-3:.0f} to "
            f"{max(fb['map_max_px'], qb['map_max_px']) / 1e-3:.0f} times the 1e-3 px that `glsim verify` asks of a DIC, so "
            "their images cannot be the ground truth of a sub-pixel DIC check.")
    if sw and {"exact-bspline3", "q4-bspline3", "fast-bspline3"} <= set(sw):
        d_fast = max(abs(a.get("apparent_u", 0) - b.get("apparent_u", 0))
                     for a, b in zip(sw["fast-bspline3"]["rows"], sw["exact-bspline3"]["rows"]))
        d_q4 = max(abs(a.get("apparent_u", 0) - b.get("apparent_u", 0))
                   for a, b in zip(sw["q4-bspline3"]["rows"], sw["exact-bspline3"]["rows"]))
        lines.append(
            f"- The rigid sweep does not separate the modes: a plate square to a distortion-free camera "
            f"projects affinely, which `fast` and `q4` reproduce exactly, so their S-curves coincide with "
            f"`exact`'s (generator-alone shift differs from exact by {d_q4:.1e} px for q4 and {d_fast:.1e} px "
            "for fast, its fp32 arithmetic). Their mapping error needs perspective, curvature or distortion "
            "(the bulge above).")
    if sw and "model" in sw and "exact-procedural" in sw and "exact-bspline3" in sw:
        mo, pr, bs = sw["model"], sw["exact-procedural"], sw["exact-bspline3"]
        mo4, bs4 = sw.get("model-spp4"), sw.get("exact-bspline3-spp4")
        lines.append(
            f"- **Interpolation.** The DIC's own S-curve (pyvale on the exact model images) reaches "
            f"{mo['max_abs_bias_u']:.1e} px bias and {mo['max_std_u']:.1e} px std at 1 spp"
            + (f", {mo4['max_abs_bias_u']:.1e} and {mo4['max_std_u']:.1e} px at 4 spp" if mo4 else "")
            + f". `exact`/`procedural` images equal the model images (grey RMS "
            f"{pr['max_grey_rms_vs_model'] * 255:.0e} 8-bit levels): pyvale reads them to within "
            f"{pr['max_abs_gen_u']:.0e} px of the model and the generator-alone shift error is "
            f"{pr['max_abs_apparent_u']:.0e} px. `exact`/`bspline3` (the current default) interpolates the "
            f"2×-oversampled reference image, a {bs['max_grey_rms_vs_model'] * 255:.1f}-level RMS grey error "
            f"that displaces the speckle by up to {bs['max_abs_apparent_u']:.1e} px (period 0.5 px = one "
            f"reference pixel, zero where the reference coordinates are whole pixels: the interpolation's "
            f"own error at the fractional position)"
            + (f", {bs4['max_abs_apparent_u']:.1e} px at 4 spp" if bs4 else "")
            + f"; pyvale, which only compares the images with each other, reads up to "
            f"{bs['max_abs_gen_u']:.1e} px of it"
            + (f" ({bs4['max_abs_gen_u']:.1e} px at 4 spp)" if bs4 else "")
            + " — the size of `glsim verify`'s 1e-3 px goal.")
    if eb and ep:
        t_sweep = ""
        if sw and "exact-procedural" in sw:
            t_sweep = (f"; {sw['exact-procedural']['render_seconds_median']:.3f} against "
                       f"{sw['exact-bspline3']['render_seconds_median']:.3f} s per 512×512 image in the sweep")
        better = (sw and "exact-procedural" in sw and sw["exact-procedural"]["max_abs_apparent_u"] is not None
                  and sw["exact-procedural"]["max_abs_apparent_u"] < 0.01 * sw["exact-bspline3"]["max_abs_apparent_u"]
                  and ep["seconds"] < 2.0 * eb["seconds"])
        lines.append(
            f"- **Cost.** `procedural` takes {ep['seconds']:.3f} s against {eb['seconds']:.3f} s per 1624×1234 "
            f"image ({ep['seconds'] / eb['seconds']:.1f}×{t_sweep}); its grey error against the exact speckle is "
            f"{ep['speckle_rms']:.1e} levels RMS against {eb['speckle_rms']:.2f} for bspline3 — bspline3 does "
            f"not reach that even at 16 spp ({f[('exact', 'bspline3', 16)]['speckle_rms']:.2f} levels, "
            f"{f[('exact', 'bspline3', 16)]['seconds']:.2f} s)."
            if ("exact", "bspline3", 16) in f else
            f"- **Cost.** `procedural` takes {ep['seconds']:.3f} s against {eb['seconds']:.3f} s per image.")
        if ep4 and sw and "model-spp4" in sw:
            lines.append(
                f"- **Samples per pixel.** 4 spp ({ep4['seconds']:.2f} s with procedural) halves the DIC's own "
                f"error on this speckle (its 1-px dot edges alias at 1 spp), but that is the DIC's error, not the "
                "generator's: the generator is exact at any spp in `exact`/`procedural`.")
        if better:
            lines.append(
                "- **Conclusion.** The data support `exact` as the default mode, and `procedural` rather than "
                "`bspline3` as the default interpolation whenever the reference is the built-in generator: it "
                "removes a generator error of the order of a DIC's own bias for less than twice the time. "
                "`bspline3` remains the only choice for reference images from file and for low-passed "
                "references (as `glsim verify` uses), where there are no dots to evaluate; its error there "
                "depends on how much of the reference lies near its Nyquist frequency (this sweep measures "
                "the unfiltered 1-px-edge speckle, the hard case, not the low-passed one). "
                "`exact`/`bspline3` is defensible for speed, not as bias-free ground truth.")
        else:
            lines.append("- **Conclusion.** The data support keeping `exact`/`bspline3`: `procedural` does not "
                         "reduce the generator's error enough for its cost here.")
    lines.append("")
    return lines
