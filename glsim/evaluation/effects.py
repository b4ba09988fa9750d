"""`glsim bench effects`: what each optical effect costs per image.

The bulge stereo pair (both cameras, step 1) at 1624×1234 by default, rendered with no effect,
each effect alone (lighting, depth of field, noise: ``demo_effects``) and all together, with the
GL and the CPU backend. Per row: median seconds per image (``Result.seconds``: geometry +
passes + read-back) over timed renders after one warm-up, the increment over the effect-free
row and its share of the all-effects row.
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import statistics
import sys
from pathlib import Path

from glsim.io import images as io
from glsim.render import Renderer
from glsim.scene import bulge_scene, demo_effects

VARIANTS = ("none", "lighting", "optics", "noise", "all")
CPU_REPS = 2


def variant(scene, name: str):
    """``scene`` with the demo's effects: none, one of them, or all."""
    full = demo_effects(scene)
    if name == "all":
        return full
    keep = {e: getattr(full, e) if e == name else None for e in ("lighting", "optics", "noise")}
    return dataclasses.replace(scene, **keep)


def time_variant(scene, backend: str, reps: int, ctx=None) -> dict:
    """Median and all seconds per image over both cameras' renders of step 1."""
    with Renderer(scene, backend, ctx=ctx) as r:
        for cam in range(len(scene.cameras)):
            r.render(cam, 1)  # warm-up: programs, textures, ray maps
        runs = [r.render(cam, 1) for _ in range(reps) for cam in range(len(scene.cameras))]
    return {"seconds": statistics.median(x.seconds for x in runs), "seconds_all": [x.seconds for x in runs],
            "stages": list(runs[-1].stages), "saturated": runs[-1].saturated}


def effects(size: tuple[int, int], reps: int) -> dict:
    from glsim.evaluation.report import machine_info
    from glsim.backends.gl.context import create_context, info

    base = bulge_scene(size=size, steps=1)
    ctx = create_context()
    try:
        machine = machine_info(info(ctx))
        rows = []
        for backend, n in (("gl", reps), ("cpu", min(reps, CPU_REPS))):
            for name in VARIANTS:
                rec = {"backend": backend, "effects": name, "reps": n,
                       **time_variant(variant(base, name), backend, n, ctx if backend == "gl" else None)}
                rows.append(rec)
                print(f"  {backend} {name}: {rec['seconds']:.3g} s", file=sys.stderr, flush=True)
    finally:
        ctx.release()
    for r in rows:
        none = next(x for x in rows if x["backend"] == r["backend"] and x["effects"] == "none")["seconds"]
        every = next(x for x in rows if x["backend"] == r["backend"] and x["effects"] == "all")["seconds"]
        r["added_seconds"] = r["seconds"] - none
        r["share_of_all"] = r["added_seconds"] / every
    return {"machine": machine, "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
            "size": list(size), "scene": f"demo_effects(bulge_scene(size={tuple(size)}, steps=1)), both cameras, step 1",
            "records": rows}


def markdown(report: dict) -> str:
    m = report["machine"]
    lines = ["# glsim effects benchmark", "",
             f"- Machine: `{m['node']}`, {m['cpu']}, {m['cores']} cores, Python {m['python']}",
             f"- GL: {m['gl']['vendor']} / {m['gl']['renderer']} / {m['gl']['version']}",
             f"- Date: {report['date']}; image {report['size'][0]}×{report['size'][1]}; {report['scene']}",
             "- Effects as `glsim demo --effects`: a spotlight (Table 1 values), 30 mm f/2 depth of field "
             "focused at 600 mm, 2 % Gaussian noise.",
             "- time: median `Result.seconds` per image (both cameras) after one warm-up each; "
             "min–max: the spread of those renders (an increment smaller than it is not resolved); "
             "added: over the no-effect row; share: added / the all-effects row's time.", "",
             "| backend | effects | reps | time per image (s) | min–max (s) | added (s) | share of all | stages run |",
             "|---|---|---|---|---|---|---|---|"]
    for r in report["records"]:
        lines.append(f"| {r['backend']} | {r['effects']} | {r['reps']} | {r['seconds']:.3g} | "
                     f"{min(r['seconds_all']):.3g}–{max(r['seconds_all']):.3g} | "
                     f"{r['added_seconds']:+.3g} | {r['share_of_all']:.0%} | {', '.join(r['stages'])} |")
    return "\n".join(lines) + "\n"


def write(report: dict, out: Path) -> str:
    text = markdown(report)
    out.mkdir(parents=True, exist_ok=True)
    io.write_text(out / "effects.json", json.dumps(report, indent=2) + "\n")
    io.write_text(out / "effects.md", text)
    return text
