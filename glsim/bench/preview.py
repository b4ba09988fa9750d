"""``glsim bench preview``: how interactive the preview is (goals: GOAL_FPS frames/s while
dragging, a refinement within GOAL_REFINE_S s). Frame times (median and 95th percentile) of the
preview core — render, overlays, rig view and panel, the whole frame — while a camera is dragged
(fast mode at the interactive size), while each parameter is dragged, and of the full-quality
refinement at the scene's size."""
from __future__ import annotations

import os
import time
from datetime import date

import numpy as np

from glsim.scene import bulge_scene, demo_effects

FULL_SIZE = (1624, 1234)
FRAME = (1280, 800)
DRAG_WIDTH = 800            # cameras rendered at 800×608 while dragging
GOAL_FPS, GOAL_REFINE_S = 15.0, 1.0
PARAMETERS = ("stereo_angle", "distance", "target_x", "focal_length", "f_number", "focus_distance",
              "light_intensity", "light_x", "noise_sigma", "speckle_size")


def _stats(times) -> dict:
    t = np.asarray(times, float)
    return {"median_s": float(np.median(t)), "p95_s": float(np.percentile(t, 95)), "n": int(t.size),
            "fps_median": float(1.0 / np.median(t))}


def _drag(pv, name: str, n: int) -> list[float]:
    c = pv.controls[name]
    v0 = pv.get(name)
    span = (c.hi - c.lo) * 0.2
    times = []
    for k in range(n):
        value = min(max(v0 + span * np.sin(2 * np.pi * (k + 1) / n), c.lo), c.hi)
        t0 = time.perf_counter()
        pv.set(name, value, dragging=True)
        pv.frame()
        times.append(time.perf_counter() - t0)
    pv.set(name, v0)
    pv.refine()
    return times


def _refine(pv, n: int) -> tuple[list[float], list[float]]:
    frames, renders = [], []
    for k in range(n):
        pv.set("stereo_angle", pv.model.rig.angle + (0.5 if k % 2 else -0.5))
        t0 = time.perf_counter()
        pv.refine()
        frames.append(time.perf_counter() - t0)
        renders.append(pv.timings["render_full"])
    return frames, renders


def preview(size=FULL_SIZE, reps: int = 30, frame=FRAME, drag_width: int = DRAG_WIDTH) -> dict:
    """The measurements as a dict (see the module docstring)."""
    from glsim.bench.report import machine_info
    from glsim.workflows.preview import Preview

    scene = bulge_scene(size=tuple(size), steps=3)
    out = {"date": date.today().isoformat(), "size": list(size), "frame": list(frame), "drag_width": drag_width,
           "reps": reps, "load_average_before": list(os.getloadavg()), "rows": []}
    for label, sc, overlays, dw in (("bulge pair", scene, (), drag_width),
                                    ("bulge pair, dragged at the size shown", scene, (), None),
                                ("bulge pair, overlays displacement+overlap+edges", scene,
                                 ("displacement", "overlap", "edges"), drag_width),
                                ("bulge pair, lighting+DOF+noise", demo_effects(scene), (), drag_width)):
        with Preview(sc, size=frame, drag_width=dw) as pv:
            if not out.get("machine"):
                out["machine"] = machine_info(pv.gl_info())
            for name in overlays:
                pv.set(f"overlay:{name}", True)
            pv.set("step", 2)
            pv.refine()
            _drag(pv, "stereo_angle", 3)           # warm-up: programs, targets
            times = _drag(pv, "stereo_angle", reps)
            res = pv.results("fast")[0]
            row = {"case": label, "drag_camera": _stats(times),
                   "drag_render_size": list(res.camera.size), "drag_mode": res.options.mode}
            frames, renders = _refine(pv, max(3, reps // 6))
            row["refine"] = _stats(frames)
            row["refine_render_only"] = _stats(renders)
            if not overlays and sc is scene and dw == drag_width:
                row["parameters"] = {name: _stats(_drag(pv, name, max(5, reps // 3))) for name in PARAMETERS}
            out["rows"].append(row)
    out["load_average_after"] = list(os.getloadavg())
    base = out["rows"][0]
    out["goals"] = {"drag_fps": GOAL_FPS, "refine_s": GOAL_REFINE_S,
                    "drag_met": base["drag_camera"]["fps_median"] >= GOAL_FPS,
                    "refine_met": base["refine"]["median_s"] <= GOAL_REFINE_S}
    return out


def _ms(s: float) -> str:
    return f"{s * 1e3:.0f}"


def markdown(r: dict) -> str:
    m = r["machine"]
    lines = [f"# Preview frame times ({r['date']})", "",
             f"Machine: {m['cpu']}, {m['cores']} cores, {m['gl']['renderer']} ({m['gl']['version']}); load average "
             f"before/after {r['load_average_before'][0]:.1f}/{r['load_average_after'][0]:.1f}.",
             f"Bulge stereo pair at {r['size'][0]}×{r['size'][1]}, preview frame {r['frame'][0]}×{r['frame'][1]}; "
             f"while dragging the cameras render in fast mode at {r['drag_width']} px wide; the refinement renders "
             f"the pair at full size in the scene's mode (exact). Frame = render + overlays + rig view + panel.", "",
             "| case | drag a camera: median / p95 (ms) | fps | refinement: median / p95 (ms) | of which the pair's render (ms) |",
             "|---|---|---|---|---|"]
    for row in r["rows"]:
        d, f, ro = row["drag_camera"], row["refine"], row["refine_render_only"]
        lines.append(f"| {row['case']} (drag at {row['drag_render_size'][0]}×{row['drag_render_size'][1]}) | "
                     f"{_ms(d['median_s'])} / {_ms(d['p95_s'])} | {d['fps_median']:.1f} | {_ms(f['median_s'])} / "
                     f"{_ms(f['p95_s'])} | {_ms(ro['median_s'])} |")
    params = r["rows"][0].get("parameters", {})
    if params:
        lines += ["", "Dragging each parameter (bulge pair, no overlays): frame median / p95 (ms)", "",
                  "| parameter | median | p95 |", "|---|---|---|"]
        lines += [f"| {k} | {_ms(v['median_s'])} | {_ms(v['p95_s'])} |" for k, v in params.items()]
    g = r["goals"]
    lines += ["", f"Goals: ≥ {g['drag_fps']:g} frames/s while dragging — {'met' if g['drag_met'] else 'not met'}; "
              f"refinement within {g['refine_s']:g} s — {'met' if g['refine_met'] else 'not met'}.", ""]
    return "\n".join(lines)
