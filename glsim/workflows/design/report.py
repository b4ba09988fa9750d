"""A design's results: per (set-up, DIC setting) maps and figures of merit, the ranking, the files.

Per set-up and DIC setting, at every subset centre of the engine (pooled over the noise and speckle
seeds, the realisations): the bias map (mean over realisations − truth) and the noise map (std over
realisations, ddof = 1) of U and V in px and mm, the valid share, and the noise floor (the std of the
static pair's measured U, V over subsets and realisations; the truth there is 0). Beside them the
quick mode's Cramér–Rao σ (median over its subset grid, and at the engine's centres). Stereo rows
(engine pyvale3d) are summarised by :func:`glsim.workflows.design.stereo.aggregate` instead: mm,
camera 0's frame, X, Y, Z and U, V, W. Settings with a strain window add the strain's maps and
figures (:func:`glsim.workflows.design.strain.aggregate`).
"""
from __future__ import annotations

import base64
import csv
import html
import io as stdio
import json
import math

import numpy as np

from glsim.io import images as io
from glsim.workflows.design import stereo, strain
from glsim.workflows.design.stats import P95, common_points, median, pct, rms
from glsim.workflows.design.spec import Design, criteria_for, smaller_is_better



def row_summary(r: dict) -> dict:
    """One row's own figures (the rows CSV)."""
    m = r["meta"]
    out = {k: m[k] for k in ("key", "kind", "setup", "setting", "subset_size", "subset_step", "shape_function",
                             "speckle_seed", "noise_seed")}
    if "ratio" in r:      # a resolution row: the sinusoid sweep
        out.update(n_subsets=int(len(r["x"])), valid_share=float(np.mean(r["valid"])),
                   spatial_resolution_px=float(r["spatial_resolution_px"]),
                   periods_px=[float(p) for p in r["periods_px"]], amplitude_ratio=[float(x) for x in r["ratio"]],
                   truth_amplitude_ratio=[float(x) for x in r["truth_ratio"]],
                   node_spacing_px=float(r["node_spacing_px"]), engine_seconds=round(float(r["engine_seconds"]), 3),
                   seconds=round(float(m.get("seconds", math.nan)), 3))
        if "amplitude_mm" in r:      # the stereo sweep: W along the plate's normal
            out.update(sweep_amplitude_mm=float(r["amplitude_mm"]),
                       spatial_resolution_mm=float(r["spatial_resolution_px"] * r["mm_per_px"]))
        if "inplane_ratio" in r:     # the stereo sweep's in-plane steps (a setting with a strain window)
            out.update(inplane_spatial_resolution_px=float(r["inplane_spatial_resolution_px"]),
                       inplane_amplitude_ratio=[float(x) for x in r["inplane_ratio"]])
        if "strain_ratio" in r:
            out.update(strain_spatial_resolution_px=float(r["strain_spatial_resolution_px"]),
                       strain_amplitude_ratio=[float(x) for x in r["strain_ratio"]],
                       truth_strain_amplitude_ratio=[float(x) for x in r["truth_strain_ratio"]])
        return out
    if "W" in r:          # a stereo row
        return {**out, **stereo.row_summary(r), **(strain.row_summary(r) if "exx" in r else {}),
                "seconds": round(float(m.get("seconds", math.nan)), 3)}
    q = np.hypot(r["quick_sigma_u"], r["quick_sigma_v"]) / math.sqrt(2)
    out.update(n_subsets=int(len(r["x"])), quick_sigma_px=median(q), quick_sigma_mm=median(q * r["scale"]),
               seconds=round(float(m.get("seconds", math.nan)), 3))
    if m["kind"] != "quick":
        ok = r["valid"] & r["truth_valid"]
        e = np.hypot(r["u"] - r["truth_u"], r["v"] - r["truth_v"])
        s = r["static_valid"]
        out.update(valid_share=float(np.mean(r["valid"])) if len(ok) else math.nan,
                   p95_abs_error_px=pct(e[ok], P95), p95_abs_error_mm=pct((e * r["scale"])[ok], P95),
                   mean_u_error_px=float(np.mean((r["u"] - r["truth_u"])[ok])) if ok.any() else math.nan,
                   mean_v_error_px=float(np.mean((r["v"] - r["truth_v"])[ok])) if ok.any() else math.nan,
                   static_std_u_px=float(np.std(r["static_u"][s])) if s.any() else math.nan,
                   static_std_v_px=float(np.std(r["static_v"][s])) if s.any() else math.nan,
                   engine_seconds=round(float(r["engine_seconds"]), 3))
        if "exx" in r:
            out.update(strain.row_summary(r))
    return out


def _stack(rows: list[dict]) -> dict | None:
    """Engine rows of one (set-up, setting) on their common subset centres: (realisations, n)."""
    if not rows:
        return None
    x, y, idx = common_points([r["x"] for r in rows], [r["y"] for r in rows])
    pick = lambda k: np.stack([r[k][i] for r, i in zip(rows, idx)])  # noqa: E731
    return {"x": x, "y": y,
            **{k: pick(k) for k in ("u", "v", "valid", "static_u", "static_v", "static_valid", "truth_u", "truth_v",
                                    "truth_valid", "scale", "quick_sigma_u", "quick_sigma_v")}}


def aggregate(design: Design, results: list[dict]) -> list[dict]:
    """One entry per (set-up, DIC setting): figures of merit (``summary``) and maps (``maps``)."""
    variants = {v.id: v for v in design.plan.variants}
    out = []
    for v in design.plan.variants:
        for s in design.settings:
            mine = [r for r in results if r["meta"]["setup"] == v.id and r["meta"]["setting"] == s.name]
            sweeps = [r for r in mine if "ratio" in r]
            mine = [r for r in mine if "ratio" not in r]
            quick = [r for r in mine if r["meta"]["kind"] == "quick"]
            q = np.concatenate([np.hypot(r["quick_sigma_u"], r["quick_sigma_v"]) / math.sqrt(2) for r in quick])
            qs = np.concatenate([r["scale"] for r in quick])
            summary = {"setup": v.id, "params": variants[v.id].params, "setting": s.name,
                       "subset_size": s.subset_size, "subset_step": s.subset_step,
                       "shape_function": s.shape_function, "quick_sigma_px": median(q),
                       "quick_sigma_mm": median(q * qs), "quick_subsets": int(len(q))}
            if s.strain is not None:
                summary.update(strain_window=s.strain_window, strain_element=s.strain_element,
                               strain_formulation=s.strain_formulation)
            maps = {"quick": quick[0]}
            measured = [r for r in mine if r["meta"]["kind"] != "quick"]
            if measured and all("exx" in r for r in measured):
                more, strain_maps = strain.aggregate(measured)
                summary.update(more)
                maps.update(strain_maps)
            st = _stack(measured) if not design.stereo else None
            if design.stereo and measured:
                more, stereo_maps = stereo.aggregate(measured)
                summary.update(more)
                maps.update(stereo_maps)
            if st is not None:
                ok = st["valid"] & st["truth_valid"]
                eu = np.where(ok, st["u"] - st["truth_u"], np.nan)
                ev = np.where(ok, st["v"] - st["truth_v"], np.nan)
                n_ok = ok.sum(axis=0)
                with np.errstate(invalid="ignore", divide="ignore"):
                    bias_u = np.where(n_ok > 0, np.nansum(eu, 0) / n_ok, np.nan)
                    bias_v = np.where(n_ok > 0, np.nansum(ev, 0) / n_ok, np.nan)
                    noise_u = np.sqrt(np.nansum((eu - bias_u) ** 2, 0) / (n_ok - 1))
                    noise_v = np.sqrt(np.nansum((ev - bias_v) ** 2, 0) / (n_ok - 1))
                noise_u[n_ok < 2], noise_v[n_ok < 2] = np.nan, np.nan
                scale = np.nanmean(st["scale"], axis=0)
                err = np.hypot(eu, ev)
                sok = st["static_valid"]
                su, sv = np.std(st["static_u"][sok]), np.std(st["static_v"][sok])
                qe = np.nanmedian(np.hypot(st["quick_sigma_u"], st["quick_sigma_v"]) / math.sqrt(2), axis=0)
                floor = float(math.sqrt((su ** 2 + sv ** 2) / 2)) if sok.any() else math.nan
                summary.update(
                    realisations=int(len(st["u"])), subsets=int(len(st["x"])), valid_share=float(st["valid"].mean()),
                    p95_abs_error_px=pct(err, P95), p95_abs_error_mm=pct(err * scale, P95),
                    rms_bias_px=rms(np.hypot(bias_u, bias_v)), rms_bias_mm=rms(np.hypot(bias_u, bias_v) * scale),
                    median_noise_px=median(np.hypot(noise_u, noise_v) / math.sqrt(2)),
                    median_noise_mm=median(np.hypot(noise_u, noise_v) / math.sqrt(2) * scale),
                    noise_floor_u_px=float(su), noise_floor_v_px=float(sv), noise_floor_px=floor,
                    noise_floor_mm=floor * median(scale), quick_sigma_at_engine_px=median(qe),
                    noise_floor_over_quick=floor / median(qe) if median(qe) > 0 else math.nan)
                maps.update(x=st["x"], y=st["y"], bias_u=bias_u, bias_v=bias_v, noise_u=noise_u, noise_v=noise_v,
                            scale=scale, quick_engine=qe)
            if sweeps:
                summary.update(_resolution_summary(sweeps, summary.get("noise_floor_px", math.nan)))
                if design.stereo:   # mm: the W noise floor of the set-up's stereo rows × the resolution on the plate
                    summary.pop("mei_px2")
                    summary["mei_W_mm2"] = summary.get("noise_floor_W_mm", math.nan) * summary["spatial_resolution_mm"]
                if "strain_spatial_resolution_px" in summary:
                    summary["strain_mei_px"] = (summary.get("strain_noise_floor_exx", math.nan)
                                                * summary["strain_spatial_resolution_px"])
                maps["sweep"] = summary["amplitude_ratio"]
            out.append({"summary": summary, "maps": maps})
    return out


def _resolution_summary(sweeps: list[dict], noise_floor_px: float) -> dict:
    """The sweep's figures for one (set-up, setting), the ratios averaged over the speckle seeds:
    spatial resolution (px, mm), the metrological efficiency indicator (noise floor × resolution)."""
    from glsim.workflows.design.resolution import spatial_resolution

    periods = sweeps[0]["periods_px"]
    ratio = np.mean([r["ratio"] for r in sweeps], axis=0)
    res = spatial_resolution(periods, ratio)
    mm = float(np.mean([r["mm_per_px"] for r in sweeps]))
    out = {"spatial_resolution_px": res, "spatial_resolution_mm": res * mm, "mei_px2": noise_floor_px * res,
           "periods_px": [float(p) for p in periods], "amplitude_ratio": [float(x) for x in ratio],
           "truth_amplitude_ratio": [float(x) for x in np.mean([r["truth_ratio"] for r in sweeps], axis=0)],
           "sweep_amplitude_px": float(sweeps[0]["amplitude_px"]),
           "sweep_node_spacing_px": float(sweeps[0]["node_spacing_px"])}
    if all("strain_ratio" in r for r in sweeps):   # a setting with a strain window: exx of the same sweep
        sr = np.mean([r["strain_ratio"] for r in sweeps], axis=0)
        sres = spatial_resolution(periods, sr)
        out.update(strain_spatial_resolution_px=sres, strain_spatial_resolution_mm=sres * mm,
                   strain_amplitude_ratio=[float(x) for x in sr],
                   truth_strain_amplitude_ratio=[float(x) for x in
                                                 np.mean([r["truth_strain_ratio"] for r in sweeps], axis=0)])
    if all("inplane_ratio" in r for r in sweeps):   # stereo: U along the plate's x (the strain's steps)
        ur = np.mean([r["inplane_ratio"] for r in sweeps], axis=0)
        out.update(inplane_spatial_resolution_px=spatial_resolution(periods, ur),
                   inplane_amplitude_ratio=[float(x) for x in ur],
                   truth_inplane_amplitude_ratio=[float(x) for x in
                                                  np.mean([r["truth_inplane_ratio"] for r in sweeps], axis=0)])
    return out


def rank(entries: list[dict], by: str) -> list[dict]:
    """Summaries sorted by criterion ``by`` (best first; NaN last), each with its ``rank``."""
    smaller = smaller_is_better(by)

    def key(e):
        v = e["summary"].get(by, math.nan)
        return (not math.isfinite(v), v if smaller else -v) if isinstance(v, float) else (True, 0)
    ranked = sorted(entries, key=key)
    return [{"rank": i + 1, **e["summary"]} for i, e in enumerate(ranked)]


# ---- files ----------------------------------------------------------------------------------------
def clean(obj):
    """``obj`` with NaN and ±∞ as None (strict JSON) and numpy scalars as Python numbers."""
    if isinstance(obj, dict):
        return {k: clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    return None if isinstance(obj, float) and not math.isfinite(obj) else obj


def write_csv(path, rows: list[dict]) -> None:
    cols = list(dict.fromkeys(k for r in rows for k in r))
    buf = stdio.StringIO()
    w = csv.DictWriter(buf, cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else v for k, v in r.items()})
    io.write_text(path, buf.getvalue())


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = stdio.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def _map(ax, x, y, values, title, shape, fig, cmap="viridis", symmetric=False, outline=None):
    ok = np.isfinite(values)
    vmax = np.nanmax(np.abs(values[ok])) if ok.any() else 1.0
    kw = {"vmin": -vmax, "vmax": vmax} if symmetric else {}
    im = ax.scatter(x[ok], y[ok], c=values[ok], s=12, marker="s", cmap="RdBu_r" if symmetric else cmap, **kw)
    if outline is not None and outline.any():   # the ROI's edge: the specimen as camera 0 sees it
        ax.contour(outline.astype(np.float32), levels=[0.5], colors="k", linewidths=0.7)
    ax.set_xlim(0, shape[1])
    ax.set_ylim(shape[0], 0)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)
    fig.colorbar(im, ax=ax, shrink=0.8)


def entry_figure(entry: dict, image_shape) -> str:
    """Error maps of one (set-up, setting): quick σ, and with an engine its noise and bias maps."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = entry["maps"]
    q = m["quick"]
    if "bias_W" in m:
        return _stereo_figure(m, image_shape)
    panels = 1 + (3 if "bias_u" in m else 0) + (2 if "strain_bias_exx" in m else 0)
    fig, axes = plt.subplots(1, panels, figsize=(3.3 * panels, 3.0), squeeze=False)
    axes = axes[0]
    _map(axes[0], q["x"], q["y"], np.hypot(q["quick_sigma_u"], q["quick_sigma_v"]) / math.sqrt(2),
         "quick: Cramér–Rao σ (px)", image_shape, fig)
    if "bias_u" in m:
        _map(axes[1], m["x"], m["y"], np.hypot(m["noise_u"], m["noise_v"]) / math.sqrt(2),
             "measured noise: std over realisations (px)", image_shape, fig)
        _map(axes[2], m["x"], m["y"], m["bias_u"], "bias U: mean − truth (px)", image_shape, fig, symmetric=True)
        _map(axes[3], m["x"], m["y"], m["bias_v"], "bias V: mean − truth (px)", image_shape, fig, symmetric=True)
    if "strain_bias_exx" in m:
        _map(axes[-2], m["strain_x"], m["strain_y"], m["strain_noise_exx"], "strain noise exx: std over realisations",
             image_shape, fig)
        _map(axes[-1], m["strain_x"], m["strain_y"], m["strain_bias_exx"], "strain bias exx: mean − truth",
             image_shape, fig, symmetric=True)
    return _png(fig)


def _stereo_figure(m: dict, image_shape) -> str:
    """A stereo entry's maps on camera 0's reference image, the ROI outlined: the quick σ (camera 0,
    px), the noise and bias maps of W (mm), the in-plane bias |(U, V)| and the shape's bias in Z (mm)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    q, roi = m["quick"], m.get("roi")
    panels = 5 + (2 if "strain_bias_exx" in m else 0)
    fig, axes = plt.subplots(1, panels, figsize=(3.3 * panels, 3.0), squeeze=False)
    axes = axes[0]
    _map(axes[0], q["x"], q["y"], np.hypot(q["quick_sigma_u"], q["quick_sigma_v"]) / math.sqrt(2),
         "quick (camera 0): Cramér–Rao σ (px)", image_shape, fig, outline=roi)
    _map(axes[1], m["x"], m["y"], m["noise_W"], "noise W: std over realisations (mm)", image_shape, fig, outline=roi)
    _map(axes[2], m["x"], m["y"], m["bias_W"], "bias W: mean − truth (mm)", image_shape, fig, symmetric=True,
         outline=roi)
    _map(axes[3], m["x"], m["y"], np.hypot(m["bias_U"], m["bias_V"]), "bias |(U, V)|: mean − truth (mm)",
         image_shape, fig, outline=roi)
    _map(axes[4], m["x"], m["y"], m["bias_Z"], "shape bias Z (reference state, mm)", image_shape, fig,
         symmetric=True, outline=roi)
    if "strain_bias_exx" in m:
        _map(axes[5], m["strain_x"], m["strain_y"], m["strain_noise_exx"], "surface strain noise exx", image_shape,
             fig, outline=roi)
        _map(axes[6], m["strain_x"], m["strain_y"], m["strain_bias_exx"], "surface strain bias exx: mean − truth",
             image_shape, fig, symmetric=True, outline=roi)
    return _png(fig)


def trend_figure(entries: list[dict]) -> str:
    """Noise versus subset size, one line per set-up and shape function: quick σ (dashed) and,
    with an engine, the measured noise floor (solid)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    groups: dict = {}
    unit = "px"
    for e in entries:
        s = e["summary"]
        groups.setdefault((s["setup"], s["subset_step"], s["shape_function"]), []).append(s)
    for i, ((setup, step, shape), ss) in enumerate(groups.items()):
        ss = sorted(ss, key=lambda s: s["subset_size"])
        size = [s["subset_size"] for s in ss]
        colour = f"C{i % 10}"
        label = f"{setup} {shape} step {step}"
        if "noise_floor_W_mm" in ss[0]:   # stereo: mm
            ax.plot(size, [s["quick_sigma_mm"] for s in ss], "--o", color=colour, label=f"{label}: quick σ (cam 0)")
            ax.plot(size, [s["noise_floor_inplane_mm"] for s in ss], "-s", color=colour,
                    label=f"{label}: noise floor U, V")
            ax.plot(size, [s["noise_floor_W_mm"] for s in ss], ":^", color=colour, label=f"{label}: noise floor W")
            unit = "mm"
            continue
        ax.plot(size, [s["quick_sigma_px"] for s in ss], "--o", color=colour, label=f"{label}: quick σ")
        if "noise_floor_px" in ss[0]:
            ax.plot(size, [s["noise_floor_px"] for s in ss], "-s", color=colour, label=f"{label}: noise floor")
    ax.set_xlabel("subset size (px)")
    ax.set_ylabel(f"σ ({unit})")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)


def _label(s: dict) -> str:
    return f"{s['setup']} {s['setting']}"


def attenuation_figure(entries: list[dict], what: str = "") -> str:
    """Measured / imposed sinusoid amplitude versus period, one line per set-up × setting, the
    90 % level and each spatial resolution marked; the truth's own ratio (the FE field) dotted.
    ``what``: "" the displacement's, "strain_" the strain's (exx over the analytic exx)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.6))
    for i, e in enumerate(x for x in entries if f"{what}amplitude_ratio" in x["summary"]):
        s, c = e["summary"], f"C{i % 10}"
        ax.plot(s["periods_px"], s[f"{what}amplitude_ratio"], "-o", color=c, label=_label(s))
        ax.plot(s["periods_px"], s[f"truth_{what}amplitude_ratio"], ":", color=c)
        if math.isfinite(s[f"{what}spatial_resolution_px"]):
            ax.axvline(s[f"{what}spatial_resolution_px"], color=c, alpha=0.4, lw=1)
    ax.axhline(0.9, color="k", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_xlabel("period (px)")
    ax.set_ylabel("measured / analytic exx amplitude" if what else "measured / imposed amplitude")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7)
    return _png(fig)


FRONTIERS = {   # (resolution key, noise floor key, x label, y label)
    "px": ("spatial_resolution_px", "noise_floor_px", "spatial resolution: period at 90 % amplitude (px)",
           "noise floor (px)"),
    "W": ("spatial_resolution_mm", "noise_floor_W_mm", "spatial resolution of W: period at 90 % amplitude (mm)",
          "noise floor of W (mm)"),
    "strain": ("strain_spatial_resolution_px", "strain_noise_floor_exx",
               "strain spatial resolution: period at 90 % exx amplitude (px)", "strain noise floor exx"),
}


def frontier_figure(entries: list[dict], kind: str = "px") -> str:
    """Noise floor versus spatial resolution, one point per set-up × setting; the points no other
    beats on both (the Pareto frontier) joined; dashed lines of constant MEI = noise × resolution.
    ``kind``: a key of :data:`FRONTIERS` (2-D px, stereo W in mm, or the strain's)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rk, nk, xlabel, ylabel = FRONTIERS[kind]
    pts = [(e["summary"][rk], e["summary"][nk], _label(e["summary"]))
           for e in entries if e["summary"].get(rk, math.nan) > 0    # log axes: NaN and 0 (noise-free) left out
           and e["summary"].get(nk, math.nan) > 0 and math.isfinite(e["summary"][rk] * e["summary"][nk])]
    fig, ax = plt.subplots(figsize=(6, 3.8))
    for i, (r, n, label) in enumerate(pts):
        ax.plot(r, n, "o", color=f"C{i % 10}", label=label)
    front = sorted(p for p in pts if not any(q[0] <= p[0] and q[1] <= p[1] and q[:2] != p[:2] for q in pts))
    if len(front) > 1:
        ax.plot([p[0] for p in front], [p[1] for p in front], "-", color="k", lw=1, label="frontier")
    if pts:
        rs = np.array([p[0] for p in pts])
        grid = np.geomspace(rs.min() / 1.5, rs.max() * 1.5, 50)
        for mei in sorted({p[0] * p[1] for p in pts}):
            ax.plot(grid, mei / grid, ":", color="grey", lw=0.7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, which="both", alpha=0.3)
    if pts:
        ax.legend(fontsize=7)
    return _png(fig)


def _cell(v) -> str:
    if isinstance(v, float):
        return "–" if not math.isfinite(v) else f"{v:.3g}"
    if isinstance(v, dict):
        return html.escape(", ".join(f"{k}={json.dumps(x)}" for k, x in v.items()) or "(base scene)")
    return html.escape(str(v))


RANK_COLUMNS = ("rank", "setup", "params", "setting", "p95_abs_error_px", "p95_abs_error_mm", "rms_bias_px",
                "median_noise_px", "noise_floor_px", "p95_abs_strain_error", "rms_strain_bias", "median_strain_noise",
                "strain_noise_floor", "spatial_resolution_px", "mei_px2", "strain_spatial_resolution_px",
                "strain_mei_px", "quick_sigma_px",
                "quick_sigma_at_engine_px",
                "noise_floor_over_quick", "valid_share")


STEREO_COLUMNS = ("rank", "setup", "params", "setting", "p95_abs_error_mm", "p95_abs_W_mm", "rms_bias_mm",
                  "rms_bias_W_mm", "median_noise_mm", "median_noise_W_mm", "noise_floor_mm", "noise_floor_inplane_mm",
                  "noise_floor_W_mm", "p95_abs_Z_mm", "noise_floor_Z_mm", "p95_abs_strain_error", "rms_strain_bias",
                  "median_strain_noise", "strain_noise_floor", "spatial_resolution_px", "spatial_resolution_mm",
                  "mei_W_mm2", "inplane_spatial_resolution_px", "strain_spatial_resolution_px", "strain_mei_px",
                  "quick_sigma_px",
                  "quick_sigma_mm", "valid_share")


def _img(alt: str, png: str) -> str:
    return f"<img alt='{alt}' src='data:image/png;base64,{png}'>"


def _resolution_section(entries: list[dict], stereo_design: bool = False) -> str:
    if not any("amplitude_ratio" in e["summary"] for e in entries):
        return ""
    if stereo_design:
        out = ("<h2>Spatial resolution (stereo): the out-of-plane sinusoid sweep</h2><p>Measured / imposed amplitude "
               "of W(x) = A·sin(2πx/p) along the normal of a flat plate facing the stereo bisector at the specimen's "
               "place, per period (camera 0's px at the plate), by pyvale's stereo DIC; the spatial resolution is the "
               "period where it falls to 90 % (dotted: the truth's own ratio).</p>"
               + _img("attenuation versus period", attenuation_figure(entries))
               + "<h2>Noise versus resolution (W)</h2><p>The W noise floor of the set-up's stereo rows against the "
               "resolution in mm; dotted lines: constant metrological efficiency indicator (mei_W_mm2).</p>"
               + _img("noise versus resolution frontier", frontier_figure(entries, "W")))
        if any("strain_amplitude_ratio" in e["summary"] for e in entries):
            out += ("<h2>Strain spatial resolution (stereo)</h2><p>Settings with a strain window add steps that move "
                    "the plate along its own x by U = A·sin(2πx/p): pyvale's surface exx (tangent t₁ = the plate's x) "
                    "fitted over the analytic exx of U at the same strain points (dotted: the FE field's own surface "
                    "strain); inplane_spatial_resolution_px is U's own resolution.</p>"
                    + _img("strain attenuation versus period", attenuation_figure(entries, "strain_"))
                    + _img("strain noise versus resolution frontier", frontier_figure(entries, "strain")))
        return out
    out = ("<h2>Spatial resolution: the sinusoid sweep</h2><p>Measured / imposed amplitude of u(x) = A·sin(2πx/p) "
           "on a flat plate per period; the spatial resolution is the period where it falls to 90 % (dotted: the "
           "truth's own ratio, the FE field's interpolation).</p>" + _img("attenuation versus period",
                                                                          attenuation_figure(entries))
           + "<h2>Noise versus resolution</h2><p>Lower left is better on both; a point on the black line is beaten on "
           "both by no other; dotted lines: constant metrological efficiency indicator (noise floor × spatial "
           "resolution).</p>" + _img("noise versus resolution frontier", frontier_figure(entries)))
    if any("strain_amplitude_ratio" in e["summary"] for e in entries):
        out += ("<h2>Strain spatial resolution</h2><p>pyvale's exx of the same sweep, its fitted amplitude over that "
                "of the analytic exx of u (∂u/∂x = A·(2π/p)·cos(2πx/p) in the setting's formulation) at the same "
                "strain points; the strain's resolution is the period where it falls to 90 % (dotted: the FE "
                "field's own strain). The subset and the strain window both smooth.</p>"
                + _img("strain attenuation versus period", attenuation_figure(entries, "strain_"))
                + _img("strain noise versus resolution frontier", frontier_figure(entries, "strain")))
    return out


def _cameras(design: Design) -> str:
    if design.stereo:
        return (f"stereo pair {html.escape(design.cameras[0])} (camera 0: its frame, its reference image's subsets) "
                f"and {html.escape(design.cameras[1])}")
    return f"camera {html.escape(design.camera)}"


CALIBRATION_COLUMNS = (("rms_px", "RMS reprojection (px)"), ("T_norm_mm", "|ΔT| (mm)"),
                       ("rotation_deg", "rotation error (°)"), ("pairs_used", "pairs used"), ("seconds", "seconds"))


def _calibration_section(calibration: dict) -> str:
    """The calibrated rig's errors against the truth per set-up (rig = "targets")."""
    setups = calibration.get("setups")
    if not setups:
        return ""
    head = "<th>set-up</th>" + "".join(f"<th>{html.escape(t)}</th>" for _, t in CALIBRATION_COLUMNS) + \
        "<th>largest intrinsic error (px)</th>"
    body = "".join(
        f"<tr><td>{html.escape(sid)}</td>" + "".join(f"<td>{_cell(r.get(k, math.nan))}</td>" for k, _ in CALIBRATION_COLUMNS)
        + f"<td>{_cell(max((abs(v) for k, v in r['errors'].items() if not k.startswith('k')), default=math.nan))}</td></tr>"
        for sid, r in setups.items())
    return ("<h2>Calibration</h2><p>Each set-up's rig calibrated from a simulated target library "
            "(glsim calib); the stereo DIC measured with these estimated cameras, so their error is in the "
            f"maps and the ranking.</p><table id=\"calibration\"><tr>{head}</tr>{body}</table>")


def html_report(design: Design, ranking: list[dict], entries: list[dict], image_shape, meta: dict) -> str:
    cols = [c for c in (STEREO_COLUMNS if design.stereo else RANK_COLUMNS) if any(c in r for r in ranking)]
    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join("<tr>" + "".join(f"<td>{_cell(r.get(c, math.nan))}</td>" for c in cols) + "</tr>" for r in ranking)
    figs = "".join(f"<h3>{html.escape(e['summary']['setup'])} ({_cell(e['summary']['params'])}), "
                   f"{html.escape(e['summary']['setting'])}</h3><img alt='error maps' src='data:image/png;base64,"
                   f"{entry_figure(e, image_shape)}'>" for e in entries)
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in meta["notes"])
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>glsim design: {html.escape(meta['spec'])}</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:1400px}}table{{border-collapse:collapse;font-size:13px}}
td,th{{border:1px solid #bbb;padding:3px 6px;text-align:right}}th{{background:#eee}}img{{max-width:100%}}</style>
</head><body>
<h1>What will my DIC measure?</h1>
<p>Spec <code>{html.escape(meta['spec'])}</code>; engine <b>{html.escape(design.engine)}</b>; {_cameras(design)},
step {design.step} against step 0; {len(design.plan.variants)} set-ups ×
{len(design.settings)} DIC settings; noise seeds {list(design.noise_seeds)}, speckle seeds
{[s for s in design.speckle_seeds if s is not None] or 'the scene’s own'}; calibration: {design.rig} rig.</p>
<h2>Ranking by {html.escape(design.rank_by)}</h2><p>{html.escape(criteria_for(design.engine)[design.rank_by][0])}</p>
<table id="ranking"><tr>{head}</tr>{body}</table>
<h2>Noise versus subset size</h2><img alt="noise versus subset size" src="data:image/png;base64,{trend_figure(entries)}">
{_resolution_section(entries, design.stereo)}
{_calibration_section(meta.get("calibration", {}))}
<h2>Maps per set-up and DIC setting</h2>{figs}
<h2>Reading this report</h2><ul>{notes}</ul>
</body></html>
"""
