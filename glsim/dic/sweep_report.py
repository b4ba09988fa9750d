"""The rigid-body sweep's report: S-curve figure, markdown, ``sweep.json`` and the GL-versus-oracle
agreement through the DIC (``glsim verify sweep``, ``sweep-compare``, ``backends``)."""
from __future__ import annotations

import json
from pathlib import Path

from glsim.dic.frontier import frontier_markdown, plot_frontier
from glsim.bench.formatting import num
from glsim.workflows.figures import save_figure
from glsim.dic.sweep import (APPARENT_STRIDE, ROI_MARGIN_PX, analyse, results_by_sequence,
                             sequence_style)
from glsim.io import images as io


def plot_sweep(res: dict, path: str | Path) -> Path:
    """The S-curves: per DIC run (columns) the bias and std of u − shift and the paired
    difference to the model sequence versus the shift; below, the DIC-free apparent-shift error
    of each glsim sequence and its grey RMS against the model images."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r["name"] for r in res["runs"]]
    ncol = max(len(runs), 2)
    fig, axes = plt.subplots(4, ncol, figsize=(6.2 * ncol, 14.0), squeeze=False)
    for j, run in enumerate(runs):
        rows = [r for r in res["results"] if r["run"] == run]
        size = rows[0]["subset_size"] if rows else "?"
        for r in rows:
            c, m, ls = sequence_style(r["sequence"])
            s = [x["shift_px"] for x in r["rows"]]
            kw = dict(color=c, marker=m, ls=ls, label=r["sequence"], ms=5, mfc="none" if r["spp"] > 1 else c)
            axes[0, j].plot(s, [x["bias_u"] for x in r["rows"]], **kw)
            axes[1, j].plot(s, [x["std_u"] for x in r["rows"]], **kw)
            if r["source"] != "model" and "gen_u" in r["rows"][0]:
                axes[2, j].plot(s, [x["gen_u"] for x in r["rows"]], **kw)
        axes[0, j].set_title(f"pyvale 2-D DIC, subset {size} px, step {res['calculate_2d']['subset_step']}, "
                             f"{res['calculate_2d']['shape_function'].lower()}, 16-bit")
        axes[0, j].set_ylabel("DIC bias: mean(u − shift) (px)")
        axes[1, j].set_ylabel("DIC std(u − shift) over subsets (px)")
        axes[2, j].set_ylabel("DIC generator share: mean(u − u_model) (px)")
        axes[0, j].legend(fontsize=7, ncol=2)
    first = [r for r in res["results"] if r["run"] == runs[0]] if runs else []
    for r in first:
        if r["source"] == "model":
            continue
        c, m, ls = sequence_style(r["sequence"])
        s = [x["shift_px"] for x in r["rows"]]
        kw = dict(color=c, marker=m, ls=ls, label=r["sequence"], ms=5, mfc="none" if r["spp"] > 1 else c)
        if "apparent_u" in r["rows"][0]:
            axes[3, 0].plot(s, [x["apparent_u"] for x in r["rows"]], **kw)
        axes[3, 1].semilogy(s, [max(x["grey_rms_vs_model"] * 255, 1e-6) for x in r["rows"]], **kw)
    axes[3, 0].set_ylabel("apparent shift − shift (px), no DIC")
    axes[3, 0].set_title("generator alone: least-squares fit of the exact model", fontsize=9)
    axes[3, 1].set_ylabel("grey RMS vs model image (8-bit levels)")
    axes[3, 1].set_title("grey difference from the exactly shifted model, ROI", fontsize=9)
    axes[3, 1].legend(fontsize=7, ncol=2)
    for ax in axes.ravel():
        if ax.has_data():
            ax.set_xlabel("imposed shift (px)")
            ax.grid(True, alpha=0.3)
            if ax.get_yscale() == "linear":
                ax.axhline(0.0, color="0.6", lw=0.6)
        else:
            ax.set_visible(False)
    fig.suptitle(f"Rigid-body sweep: {res['size'][0]}×{res['size'][1]} px, plate square to the camera, "
                 f"{res['mm_per_px']:.4g} mm/px; model = Boolean speckle evaluated at the exactly shifted "
                 "coordinates (hollow: 4 spp)", fontsize=10)
    return save_figure(fig, path, dpi=100)


def sweep_markdown(sweep: dict) -> list[str]:
    """The sweep part of sweep.md: settings, amplitudes, per-shift tables, timings."""
    m, c2 = sweep["machine"], sweep["calculate_2d"]
    runs = sweep["runs"]
    first = results_by_sequence(sweep)
    lines = [
        f"- Machine: `{m['node']}`, {m['cpu']}, {m['cores']} cores; GL: {m['gl']['renderer']}; {sweep['date']}",
        f"- Scene: one {sweep['size'][0]}×{sweep['size'][1]} px camera square onto a flat 48 × 42 mm plate at "
        f"300 mm ({sweep['mm_per_px']:.5g} mm/px), built-in speckle (5 px dots, 1 px edges, seed "
        f"{sweep['speckle_seed']}), no lighting, blur or noise; {sweep['bit_depth']}-bit TIFF; shifts along "
        f"{sweep['direction']}: " + ", ".join(f"{s:g}" for s in sweep["shifts_px"]) + " px = "
        + ", ".join(f"{s:.4g}" for s in sweep["shift_mm"]) + " mm",
        "- Sequences: `model` = the Boolean speckle evaluated exactly (`speckle.evaluate`) at the exactly "
        "shifted reference coordinates of every sample (float64 ray–plane), box-filtered like the renderer; "
        f"the others are glsim renders (backend {sweep['backend']}) named mode-interpolation; `-spp4`: 2×2 "
        "samples per pixel, otherwise 1",
        f"- DIC: pyvale {next(iter(first.values()))['pyvale']} `calculate_2d`, "
        + ", ".join(f"`{k}={v}`" for k, v in c2.items())
        + "; runs " + ", ".join(f"{r['name']} (subset {r['subset_size']} px)" for r in runs)
        + f"; ROI {sweep['roi_pixels']} px (plate covered at every shift, eroded {ROI_MARGIN_PX} px)",
        "- **DIC bias** = mean over the valid subsets of (u − imposed shift), **std** its population std "
        "(v: imposed 0); **DIC generator share** = mean of (u − u_model) at the same subsets, the model "
        "sequence with the same spp (the DIC's own subset-wise error cancels in the pair); **generator "
        "alone** = `apparent_shift`: the shift (u, v) that makes the exact model best fit the glsim image "
        f"in least squares (Gauss–Newton, every {APPARENT_STRIDE}nd row and column of the ROI, the model "
        "evaluated at any shift, so no interpolation and no DIC), minus the imposed shift; **grey RMS** = "
        "|image − model image| over the ROI in 8-bit grey levels (float images, before quantisation)",
        "", "## S-curve amplitudes (maximum over the 11 shifts)", "",
        "| sequence | render (s/image) | " + " | ".join(f"{r['name']} max abs bias (px) | {r['name']} max std (px)"
                                                  for r in runs)
        + f" | DIC generator share, {runs[0]['name']} (px) | generator alone, u (px) | generator alone, v (px) "
          "| grey RMS vs model |",
        "|---|---|" + "---|---|" * len(runs) + "---|---|---|---|"]
    for name, r in first.items():
        cells = []
        for run in runs:
            rr = results_by_sequence(sweep, run["name"])[name]
            cells += [num(rr["max_abs_bias_u"], ".1e"), num(rr["max_std_u"], ".1e")]
        grey = r["max_grey_rms_vs_model"] * 255
        lines.append(f"| {name} | {r['render_seconds_median']:.3f} | " + " | ".join(cells)
                     + f" | {num(r['max_abs_gen_u'], '.1e')} | {num(r['max_abs_apparent_u'], '.1e')} | "
                     f"{num(r['max_abs_apparent_v'], '.1e')} | {'0' if r['source'] == 'model' else format(grey, '.2g')} |")
    valid = [next(iter(results_by_sequence(sweep, run["name"]).values())) for run in runs]
    lines += ["", "Valid subsets: " + ", ".join(f"{run['name']} {v['n_valid']}/{v['n_subsets']}" for run, v in zip(runs, valid))
              + " (every sequence, every shift). Render times are medians per 512×512 image on this machine "
                "(the model: the numpy evaluation in float64).", ""]
    for run in runs:
        rows = results_by_sequence(sweep, run["name"])
        lines += [f"## DIC bias ± std per shift, {run['name']} (subset {run['subset_size']} px), px", "",
                  "| shift (px) | " + " | ".join(rows) + " |", "|---|" + "---|" * len(rows)]
        for k, sh in enumerate(sweep["shifts_px"]):
            lines.append(f"| {sh:.1f} | " + " | ".join(
                f"{r['rows'][k]['bias_u']:+.1e} ± {r['rows'][k]['std_u']:.1e}" for r in rows.values()) + " |")
        lines.append("")
    gen = [r for r in first.values() if r["source"] != "model"]
    lines += ["## Generator error per shift", "",
              f"Per glsim sequence: generator alone u (px, no DIC) / DIC generator share mean(u − u_model) "
              f"({runs[0]['name']}, px) / grey RMS vs model (8-bit levels).", "",
              "| shift (px) | " + " | ".join(r["sequence"] for r in gen) + " |", "|---|" + "---|" * len(gen)]
    for k, sh in enumerate(sweep["shifts_px"]):
        lines.append(f"| {sh:.1f} | " + " | ".join(
            f"{r['rows'][k].get('apparent_u', float('nan')):+.1e} / {r['rows'][k].get('gen_u', float('nan')):+.1e} / "
            f"{r['rows'][k]['grey_rms_vs_model'] * 255:.2g}" for r in gen) + " |")
    sec = sweep.get("seconds") or {}
    dic = sum(r["dic_seconds"] for r in sweep["results"])
    lines += ["", f"Timings: render, model images and writing {sec.get('render_and_write', float('nan')):.0f} s; "
              f"apparent-shift fits {sec.get('apparent_shift', float('nan')):.0f} s; pyvale `calculate_2d` "
              f"{dic:.0f} s in all ({len(sweep['results'])} sequence × run calls).", ""]
    return lines


def results_markdown(sweep: dict | None, accuracy: dict | None) -> str:
    """sweep.md: the sweep (if measured) and the frontier (if accuracy.json exists)."""
    lines = ["# Rigid-body sweep (DIC S-curve) and accuracy/time frontier", "",
             "Regenerate: `make sweep` (render, pyvale, report) or `glsim verify frontier` "
             "(frontier.png and this file from sweep.json and accuracy.json).", ""]
    if sweep is not None:
        lines += sweep_markdown(sweep)
    if accuracy is not None:
        lines += frontier_markdown(accuracy, sweep)
    return "\n".join(lines) + "\n"


def report(exchange: str | Path | None, results_dir: str | Path, accuracy_path: str | Path | None = None) -> dict | None:
    """Analyse the exchange folder (if given) into sweep.json/png, then write sweep.md and
    frontier.png from sweep.json and accuracy.json (whichever exist)."""
    results_dir = Path(results_dir)
    sweep = None
    if exchange is not None:
        sweep = analyse(exchange)
        io.write_text(results_dir / "sweep.json", json.dumps(sweep, indent=2))
        plot_sweep(sweep, results_dir / "sweep.png")
    elif (results_dir / "sweep.json").is_file():
        sweep = json.loads((results_dir / "sweep.json").read_text())
    accuracy_path = Path(accuracy_path) if accuracy_path else results_dir / "accuracy.json"
    accuracy = json.loads(accuracy_path.read_text()) if accuracy_path.is_file() else None
    if accuracy is not None:
        plot_frontier(accuracy, sweep, results_dir / "frontier.png")
    if sweep is not None or accuracy is not None:
        io.write_text(results_dir / "sweep.md", results_markdown(sweep, accuracy))
    return sweep


def backend_agreement(gl: dict, cpu: dict) -> dict:
    """GL against the CPU oracle through the DIC: for every glsim sequence and subset size in
    both sweeps, the largest |Δ bias| and |Δ std| of u over the shifts (px), next to the DIC's
    own noise (the largest std of u on the exact model images)."""
    key = lambda r: (r["sequence"], r["run"])  # noqa: E731
    cpu_by = {key(r): r for r in cpu["results"]}
    rows = []
    for r in gl["results"]:
        c = cpu_by.get(key(r))
        if r["source"] == "model" or c is None:
            continue
        noise = max(m["max_std_u"] for m in gl["results"] if m["source"] == "model" and m["run"] == r["run"])
        rows.append({"sequence": r["sequence"], "run": r["run"], "dic_noise_px": noise,
                     "max_delta_bias_px": max(abs(a["bias_u"] - b["bias_u"]) for a, b in zip(r["rows"], c["rows"])),
                     "max_delta_std_px": max(abs(a["std_u"] - b["std_u"]) for a, b in zip(r["rows"], c["rows"]))})
    return {"gl": gl["machine"], "rows": rows}


def backend_markdown(agreement: dict) -> str:
    lines = ["# GL against the CPU oracle, through the DIC", "",
             "The rigid-body sweep rendered by both backends and measured by pyvale's 2-D DIC; "
             "Δ = GL − CPU over the 11 shifts, px; DIC noise = the largest std of u on the exact "
             "model images.", "",
             r"| sequence | subset | max \|Δ bias\| (px) | max \|Δ std\| (px) | DIC noise (px) |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['sequence']} | {r['run']} | {r['max_delta_bias_px']:.2e} | {r['max_delta_std_px']:.2e} "
              f"| {r['dic_noise_px']:.2e} |" for r in agreement["rows"]]
    return "\n".join(lines) + "\n"
