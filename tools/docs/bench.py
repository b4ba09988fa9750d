"""Generators of the other results files: scaling.json, the committed FE solution
(examples/fe_bulge), library.json, preview.json, quadratic.json and glsim check's reports."""
from __future__ import annotations

from glsim.bench.formatting import ratio, sig
from glsim.bench.report import machine_line


# ---- scaling.json: docs/scaling.md -------------------------------------------------------------
def _sc_pts(sc: dict, key: str = "elements") -> list[dict]:
    return [r for r in sc[key] if "renderers" in r]


def _host(r: dict, modes=("fast", "q4", "exact")) -> list[float]:
    return [r["renderers"][m]["host_ms"] for m in modes if r["renderers"].get(m, {}).get("host_ms") is not None]


def _host_range(pts: list[dict], modes) -> str:
    host = [h for r in pts for h in _host(r, modes)]
    return f"{sig(min(host))}–{sig(max(host))} ms"


def scaling_host(sc: dict) -> str:
    """docs/scaling.md: the host time per render over the element sweep."""
    pts = _sc_pts(sc)
    W, H = pts[0]["size"]
    fast = [_host(r, ("fast",)) for r in (pts[0], pts[-1])]
    return (f"Measured (`bench/results/scaling.json`, {W}×{H}, the calling thread's CPU per render less its "
            f"read-back waits, median): q4 and exact {_host_range(pts, ('q4', 'exact'))} from "
            f"{pts[0]['elements']:,} to {pts[-1]['elements']:,} elements; fast {sig(fast[0][0])} ms at "
            f"{pts[0]['elements']:,} and {sig(fast[1][0])} ms at {pts[-1]['elements']:,} — it draws every element's "
            "triangles, and llvmpipe runs the vertex stage on the calling thread (a GPU runs it on the GPU).")


def scaling_oracle(sc: dict) -> str:
    """docs/scaling.md: the oracle at the largest element count."""
    o = max((r for r in sc["oracle"] if "seconds" in r), key=lambda r: r["elements"])
    small = min((r for r in sc["oracle"] if "seconds" in r), key=lambda r: r["elements"])
    return (f"At {o['elements']:,} elements it renders the {o['size'][0]}×{o['size'][1]} plate in {sig(o['seconds'])} s "
            f"({ratio(o['seconds'], small['seconds'])} its time at {small['elements']:,}) with a peak of "
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
        lines.append(f"| {r['elements']:,} | " + " | ".join(ratio(t(r, m), rl) for m in ("fast", "q4", "exact"))
                     + f" | {sig(rl)} | " + " | ".join(sig(t(r, m)) for m in ("fast", "q4", "exact")) + " | "
                     + " / ".join(sig(r["renderers"][m]["host_ms"]) for m in ("fast", "q4", "exact")) + " |")
    return "\n".join(lines)


def scaling_passes(sc: dict) -> str:
    """docs/scaling.md: the exact mode's passes over the element sweep."""
    from glsim.bench.scaling import PASSES_NOTE, passes_table
    return f"{PASSES_NOTE} One render per element count, after the timed ones:\n\n" + passes_table(sc["elements"], "exact")


def scaling_goals(sc: dict) -> str:
    """docs/scaling.md: the scaling goals as the run judged them, and what grows with the pixel count."""
    pts = {r["elements"]: r for r in _sc_pts(sc)}
    t = lambda r, m: r["renderers"][m]["median_s"]
    big = [r for n, r in pts.items() if t(r, "exact") < t(r, "riley")]
    lines = ["How the scaling goals fared on this machine (`goals` in scaling.json):", ""]
    for g in sc["goals"]:
        lines.append(f"- **{g['goal']}: {'met' if g['met'] else 'not met' if g['met'] is False else 'not measured'}.** "
                     f"{g['measured']}.")
    if big:
        lines.append(f"- exact takes less time than riley from {min(r['elements'] for r in big):,} elements on ("
                     + ", ".join(ratio(t(r, 'exact'), t(r, 'riley')) for r in sorted(big, key=lambda r: r['elements']))
                     + "). Below that, the exact mode pays for its per-sample arithmetic: the float64 ray/patch "
                     "intersection, the reference projection and the cubic taps.")
    sizes = _sc_pts(sc, "sizes")
    mpx = lambda r: r["size"][0] * r["size"][1] / 1e6
    lines += ["", "Against the pixel count, the host time of q4 and exact (the larger of the two): "
              + ", ".join(f"{sig(max(_host(r, ('q4', 'exact'))))} ms at {mpx(r):.1f} Mpx" for r in sizes)
              + "; fast's, which is llvmpipe's vertex stage on the calling thread, stays with the element count: "
              + ", ".join(f"{sig(_host(r, ('fast',))[0])} ms" for r in sizes) + ".", "",
              f"Against image size, at {sizes[0]['elements']:,} elements: fast takes "
              f"{ratio(min(t(r, 'fast') / t(r, 'riley') for r in sizes), 1)}–"
              f"{ratio(max(t(r, 'fast') / t(r, 'riley') for r in sizes), 1)} riley's time from {mpx(sizes[0]):.1f} to "
              f"{mpx(sizes[-1]):.1f} Mpx, and exact {ratio(t(sizes[0], 'exact'), t(sizes[0], 'riley'))} at "
              f"{mpx(sizes[0]):.1f} Mpx and {ratio(t(sizes[-1], 'exact'), t(sizes[-1], 'riley'))} at {mpx(sizes[-1]):.1f} Mpx."]
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
    from glsim.bench.library import summary
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
            f"({hi[0]}, which makes a new reference) per frame (median). The preview's goals: ≥ {g['drag_fps']:g} frames/s "
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
    from glsim.bench.quadratic import markdown
    body = markdown(q).split("\n", 2)[2]          # without the page title
    return body


def quadratic_rows(q: dict) -> str:
    """The Q8 rows of the accuracy table: GL and oracle per mode, mapping error and time."""
    from glsim.bench.quadratic import mode_label
    m = next(x for x in q["meshes"] if x["kind"] == "quad8")
    exact = next(r["time"] for r in m["rows"] if r["backend"] == "gl" and r["mode"] == "exact")
    lines = [f"Q8 elements (`glsim bench quadratic`: a paraboloid of {m['elements']} Q8 elements of about "
             f"{m['element_px']:.0f} px, against its closed form, {q['size'][0]}×{q['size'][1]} px, 1 spp; "
             f"{machine_line(q['machine'])}, {q['date']}):", "",
             "| backend | mode | mapping error mean / max (ref px) | time / GL exact | time (s) |", "|---|---|---|---|---|"]
    lines += [f"| {r['backend']} | {mode_label(r)} | {sig(r['map_mean'])} / {sig(r['map_max'])} | {sig(r['time'] / exact)} | "
              f"{sig(r['time'])} |" for r in m["rows"]]
    return "\n".join(lines)


def quadratic_fast(q: dict) -> str:
    """The fast mode's error against its piece count (the 1/n² law)."""
    m = next(x for x in q["meshes"] if x["kind"] == "quad8")
    fast = sorted((r for r in m["rows"] if r["backend"] == "gl" and r["mode"] == "fast"), key=lambda r: r["pieces"])
    steps = " → ".join(sig(r["map_mean"]) for r in fast)
    ns = ", ".join(str(r["pieces"]) for r in fast)
    ratios = ", ".join(sig(a["map_mean"] / b["map_mean"]) for a, b in zip(fast, fast[1:]))
    return (f"The fast mode's error is the chord error of the pieces: on Q8 it goes {steps} px mean for n = {ns} "
            f"pieces per side (each halving of the piece size divides it by {ratios}; 1/n² gives 4).")


def check_drivers(*reports: dict) -> str:
    """README: the drivers `glsim check` was run on (bench/results/check-*.json), check by check
    (the first report's, by name; "—" where a run predates a check, "not run" where it was
    skipped on that driver: ``glsim check --skip``; "crashed" where the driver ended its process)."""
    lines = ["| check | bound | " + " | ".join(machine_line(r["machine"]) + f", {r['date']}, {sig(r['seconds'])} s" for r in reports) + " |",
             "|---|---|" + "---|" * len(reports)]
    for row in reports[0]["checks"]:
        name = row["name"]
        cells = [_check_cell(r, next((c for c in r["checks"] if c["name"] == name), None), name) for r in reports]
        lines.append(f"| {name} | {sig(row['bound'])} {row['unit']} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _check_cell(report: dict, c: dict | None, name: str) -> str:
    """One driver's cell of :func:`check_drivers`: check ``name``'s row ``c`` of ``report``."""
    if c is None:
        return "not run" if name in report.get("skipped", ()) else "—"
    if c["passed"] is None:
        return "skipped"
    if c["value"] is None:
        return "crashed **✗**"
    return f"{sig(c['value'])} {'✓' if c['passed'] else '**✗**'}"


def jacobian(report: dict) -> str:
    """docs/jacobian.md: the Jacobian's time against a render and finite differences
    (bench/results/jacobian.json)."""
    from glsim.bench.jacobian import caption, table
    return table(report) + "\n\n" + caption(report)


def throughput(report: dict) -> str:
    """README: stereo pairs/s one at a time and pipelined (bench/results/throughput.json)."""
    from glsim.bench.throughput import table
    return table(report)


def throughput_change(before: dict, after: dict) -> str:
    """docs/performance.md: pipelined pairs/s per mode of two throughput runs on one machine, one
    after the other (the renderer before and after a change), and their ratio."""
    old = {(r["mode"], r["spp"]): r for r in before["rows"]}
    lines = [f"{machine_line(after['machine'])}; before {before['date'][:16]}, after {after['date'][:16]}", "",
             "| mode | spp | pairs/s before | pairs/s after | after / before |", "|---|---|---|---|---|"]
    for r in after["rows"]:
        b = old.get((r["mode"], r["spp"]))
        if b is not None:
            lines.append(f"| {r['mode']} | {r['spp']} | {sig(b['pipelined_pairs_per_s'], 3)} | "
                         f"{sig(r['pipelined_pairs_per_s'], 3)} | "
                         f"{r['pipelined_pairs_per_s'] / b['pipelined_pairs_per_s']:.2f} |")
    return "\n".join(lines)
