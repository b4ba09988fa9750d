"""`glsim bench throughput`: stereo pairs per second delivered to numpy as the cameras' 8-bit images.

The scaling plate (fronto-parallel, 600 mm before camera 0 of the 30° stereo rig, 70 % of
its image, k1 = −0.1, Catmull–Rom cubic, :func:`glsim.bench.scaling.plate_scene`) meshed
with ELEMENTS quad4, seen by both cameras of the rig. glsim GL renders it in modes fast, q4 and
exact at 1, 4 and 16 samples per pixel, each image quantised to uint8 on the GPU
(``quantize=True``), in two ways: one render at a time (``Renderer.render``), and pipelined
(``Renderer.render_many``, depth 2: the next image's passes are queued before this one's
read-back is mapped). Each repetition renders PAIRS stereo pairs each way for every row in turn
(interleaved), after two warm-up pairs; per row the median over repetitions.

- **pairs/s**: stereo pairs (cameras 0 and 1) delivered to numpy per wall second.
- **host ms / image**: one at a time, pipelined, and pipelined with each pair a load step not
  rendered before (the plate moved by STEP_MM: what a library over a time series does; the
  step's geometry, shape checks and uploads are made then; on a second renderer on the same
  context, so that the first keeps step 0's views cached, after two such pairs of warm-up).
  The rendering thread's CPU time outside its waits for the GPU's read-backs
  (:func:`glsim.backends.gl.timing.driver_time`) — the Python and numpy work per image and the
  driver's command setup. The JSON also keeps the wall time outside those waits
  (``*_host_wall_ms``): on llvmpipe it adds the waits for a core that the driver's render
  threads hold.
- **other pixel stage**: pairs/s pipelined with the pixel stage the driver does not get by
  default (:mod:`glsim.backends.gl.plan`: exact and q4's samples as fragment passes on depth
  layers or compute passes over pixel lists, the box filter and quantisation as fragment or
  compute passes; llvmpipe's default is fragment, a GPU's compute), timed in the same
  repetitions.
- **same bytes**: the pipelined images, and those of the other pixel stage, equal the
  one-at-a-time ones bit for bit (checked on every repetition).
- **glsim / riley**: glsim's pipelined seconds per image (a pair's time / 2) over
  riley-raster's (PyPI ``riley-raster``, all cores, its own 2048² texture, camera 0 of the same
  plate at the same samples per pixel), timed in the same repetitions; "—" when not installed.
- **passes**: one pair of the row timed pass by pass (:meth:`GLBackend.pass_times`, the driver
  finished around each draw and dispatch), the largest three, and "rest": the pair's wall time
  outside the passes (read-backs, clears, Python).

Writes ``throughput.json`` and ``throughput.md``; only the full run writes to bench/results.
"""
from __future__ import annotations

import datetime
import math
import statistics
import time

from glsim.bench.formatting import num

FULL_SIZE = (1624, 1234)
QUICK_SIZE = (406, 308)
ELEMENTS = 8_000
QUICK_ELEMENTS = 2_000
PAIRS = 3
REPS = 3
MODES = ("fast", "q4", "exact")
SPPS = (1, 4, 16)
QUICK_SPPS = (1, 4)
DEPTH = 2
# the GPU throughput goals, on an NVIDIA H100/H200 through EGL at 1624×1234, 8-bit images (pairs/s)
GOALS = {("exact", 1): 300, ("exact", 4): 150, ("fast", 1): 1000}
GOAL_HOST_MS = 1.0
GOAL_RILEY_EXACT_4 = 10.0     # riley-raster on all cores at least this many times slower (exact, 4 spp)
STEP_MM = 0.001               # the plate's translation per load step (new-step pairs)


def _scene(size: tuple[int, int], elements: int, steps: int = 0):
    """The scaling plate seen by both cameras of the stereo rig, with ``steps`` load steps
    after step 0 (rigid translations by STEP_MM along x each)."""
    import dataclasses

    from glsim.bench.scaling import K1, plate_scene
    from glsim.scene import stereo_rig
    from glsim.scene.camera import Distortion

    scene = plate_scene(size, elements)
    cam0 = scene.cameras[0]
    cam1 = stereo_rig(size=size, fx=cam0.fx, distortion=Distortion(k1=K1))[1]
    plate = dataclasses.replace(scene.specimen.plate, translations=tuple((STEP_MM * i, 0.0, 0.0)
                                                                          for i in range(1, steps + 1)))
    return dataclasses.replace(scene, cameras=(cam0, cam1),
                               specimen=dataclasses.replace(scene.specimen, plate=plate))


def _jobs(pairs: int, mode: str, spp: int, steps=None) -> list[dict]:
    """Stereo pairs of step 0, or one pair of each of ``steps``."""
    return [{"camera": c, "step": s, "quantize": True, "mode": mode, "samples_per_pixel": spp}
            for s in (steps if steps is not None else [0] * pairs) for c in (0, 1)]


def _riley(size: tuple[int, int], spp: int, elements: int):
    """A callable rendering camera 0's plate with riley-raster at ``spp``, or None, and its name."""
    try:
        import riley
    except ImportError:
        return None, "riley-raster not installed"
    from importlib.metadata import version

    from glsim.bench.accuracy import riley_setup
    from glsim.bench.scaling import K1, plate_layout

    mesh, camera, config = riley_setup(size, *plate_layout(elements), sub_sample=math.isqrt(spp), k1=K1)
    return (lambda: riley.raster(mesh, camera, config)), f"riley-raster {version('riley-raster')}"


def throughput(size=FULL_SIZE, reps: int = REPS, pairs: int = PAIRS, spps=SPPS, elements: int = ELEMENTS,
               log=print) -> dict:
    """Measure every row (see the module text); returns the report."""
    from glsim.backends.gl.plan import PIXEL_STAGES
    from glsim.backends.gl.timing import driver_time
    from glsim.bench.report import gl_info, machine_info
    from glsim.render import Renderer

    steps = len(MODES) * len(spps) * (reps * pairs + 3)   # the new-step pairs': each load step rendered once
    scene = _scene(tuple(size), elements, steps)
    fresh = iter(range(1, steps + 1))
    rows = []
    # new steps on a second renderer (same context and programs), so that they do not evict
    # step 0's views from the first one's caches (STEPS_KEPT)
    with Renderer(scene, "gl") as r, Renderer(scene, "gl", ctx=r.backend.ctx) as new:
        machine, elements = machine_info(gl_info(r)), len(r.mesh.quads)
        stage = r.backend.stage
        other = next(x for x in PIXEL_STAGES if x != stage)
        for mode in MODES:
            for spp in spps:
                jobs = _jobs(pairs, mode, spp)
                riley, riley_name = _riley(tuple(size), spp, elements)
                ways = ("single", "pipelined", "fresh", "other")
                for _ in range(2):   # warm-up: programs, targets, ray maps
                    list(r.render_many(_jobs(1, mode, spp)))
                    list(new.render_many(_jobs(1, mode, spp, [next(fresh)])))
                    with r.backend.in_stage(other):
                        list(r.render_many(_jobs(1, mode, spp)))
                row = {"mode": mode, "spp": spp, "single_s": [], "pipelined_s": [], "single_host_ms": [],
                       "pipelined_host_ms": [], "single_host_wall_ms": [], "pipelined_host_wall_ms": [],
                       "fresh_s": [], "fresh_host_ms": [],
                       "other_s": [], "other_stage": other,
                       "riley_s": [], "riley": riley_name, "same_bytes": True}
                if riley is not None:
                    riley()
                single = []   # this repetition's one-at-a-time images (ways[0])
                for _ in range(reps):
                    for way in ways:
                        todo = (_jobs(pairs, mode, spp, [next(fresh) for _ in range(pairs)]) if way == "fresh"
                                else jobs)
                        if way == "other":
                            with r.backend.in_stage(other):
                                t = time.perf_counter()
                                out = list(r.render_many(todo, depth=DEPTH))
                                row["other_s"].append(time.perf_counter() - t)
                            row["same_bytes"] &= all(a.tobytes() == b.image.tobytes() for a, b in zip(single, out))
                            continue
                        with driver_time() as d:
                            t, c = time.perf_counter(), time.thread_time()
                            out = ([r.render(**j) for j in todo] if way == "single"
                                   else list((new if way == "fresh" else r).render_many(todo, depth=DEPTH)))
                            wall, cpu = time.perf_counter() - t, time.thread_time() - c
                        host_wall, host_cpu = d.host_seconds(wall, cpu)
                        row[f"{way}_s"].append(wall)
                        row[f"{way}_host_ms"].append(host_cpu / len(todo) * 1e3)
                        if way == "fresh":
                            continue
                        row[f"{way}_host_wall_ms"].append(host_wall / len(todo) * 1e3)
                        if way == "single":
                            single = [x.image for x in out]
                        else:
                            row["same_bytes"] &= all(a.tobytes() == b.image.tobytes() for a, b in zip(single, out))
                    if riley is not None:
                        t = time.perf_counter()
                        riley()
                        row["riley_s"].append(time.perf_counter() - t)
                with r.backend.pass_times() as p:
                    t = time.perf_counter()
                    list(r.render_many(_jobs(1, mode, spp)))
                    row["passes_wall_s"] = time.perf_counter() - t
                row["passes"] = dict(p)
                rows.append(_summary(row, pairs))
                log(f"throughput: {mode} {spp} spp: {rows[-1]['pipelined_pairs_per_s']:.3g} pairs/s pipelined")
    return {"size": list(size), "elements": elements, "pairs": pairs, "reps": reps, "depth": DEPTH, "warmup": 2,
            "stage": stage,
            "machine": machine, "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "rows": rows}


def _summary(row: dict, pairs: int) -> dict:
    out = {k: row[k] for k in ("mode", "spp", "riley", "same_bytes", "passes", "passes_wall_s")}
    for way in ("single", "pipelined"):
        s = statistics.median(row[f"{way}_s"])
        out[f"{way}_pairs_per_s"] = pairs / s
        out[f"{way}_images_per_s"] = 2 * pairs / s
        out[f"{way}_host_ms"] = statistics.median(row[f"{way}_host_ms"])
        out[f"{way}_host_wall_ms"] = statistics.median(row[f"{way}_host_wall_ms"])
        out[f"{way}_s_all"] = row[f"{way}_s"]
    out["fresh_pairs_per_s"] = pairs / statistics.median(row["fresh_s"])
    out["other_stage"] = row["other_stage"]
    out["other_pairs_per_s"] = pairs / statistics.median(row["other_s"]) if row["other_s"] else None
    out["other_s_all"] = row["other_s"]
    out["fresh_host_ms"] = statistics.median(row["fresh_host_ms"])
    out["riley_s"] = statistics.median(row["riley_s"]) if row["riley_s"] else None
    out["riley_s_all"] = row["riley_s"]
    per_image = 1.0 / out["pipelined_images_per_s"]
    out["glsim_over_riley"] = per_image / out["riley_s"] if out["riley_s"] else None
    return out


def table(report: dict) -> str:
    """The results table, with the machine and the run's settings (README's generated region)."""
    from glsim.bench.report import machine_line

    W, H = report["size"]
    lines = [f"{machine_line(report['machine'])}; {report['date']}", "",
             "| mode | spp | pairs/s one at a time | pairs/s pipelined | images/s pipelined | pipelined / one "
             "at a time | pairs/s pipelined, other pixel stage | host ms / image (one / pipelined / new step) | "
             "same bytes | glsim / riley per image | largest passes (ms) and rest |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        passes = sorted(r["passes"].items(), key=lambda kv: -kv[1])
        rest = r["passes_wall_s"] - sum(r["passes"].values())
        shown = ", ".join(f"{k} {v * 1e3:.3g}" for k, v in passes[:3]) + f"; rest {rest * 1e3:.3g}"
        ratio = num(r["glsim_over_riley"], ".3g") if r["glsim_over_riley"] is not None else "—"
        lines.append(f"| {r['mode']} | {r['spp']} | {r['single_pairs_per_s']:.3g} | {r['pipelined_pairs_per_s']:.3g} | "
                     f"{r['pipelined_images_per_s']:.3g} | {r['pipelined_pairs_per_s'] / r['single_pairs_per_s']:.2f} | "
                     f"{_other(r)} | "
                     f"{r['single_host_ms']:.2g} / {r['pipelined_host_ms']:.2g} / {_cell(r, 'fresh_host_ms', '.2g')} | "
                     f"{'yes' if r['same_bytes'] else 'NO'} | "
                     f"{ratio} | {shown} |")
    riley = next((r["riley"] for r in report["rows"]), "—")
    lines += ["", f"The scaling plate ({report['elements']} quad4, k1 = −0.1, Catmull–Rom cubic) at {W}×{H} px, "
              f"both cameras of the 30° rig; {report['pairs']} pairs per way and repetition, {report['reps']} "
              f"interleaved repetitions after {report['warmup']} warm-up pairs, medians; pipelined: `render_many` "
              f"depth {report['depth']}; new step: as pipelined, each pair a load step not rendered before. "
              f"Pixel stage: {report.get('stage', 'fragment')}, "
              "the driver's (`glsim.backends.gl.plan`); the other one in its own column. "
              f"Peer: {riley}, camera 0 only."]
    return "\n".join(lines)


def _other(row: dict) -> str:
    """The other pixel stage's cell: its name and pairs/s, or "—" (results made before it)."""
    value = row.get("other_pairs_per_s")
    return "—" if value is None else f"{row['other_stage']} {value:.3g}"


def _cell(row: dict, key: str, fmt: str) -> str:
    """``row[key]`` formatted, or "—" in results made before it was measured."""
    value = row.get(key)
    return "—" if value is None else format(value, fmt)


def markdown(report: dict) -> str:
    return "\n".join(["# glsim throughput benchmark: stereo pairs delivered as 8-bit images", "", table(report), "",
                      "The GPU throughput goals apply to an NVIDIA H100/H200 through EGL at 1624×1234: "
                      + ", ".join(f"{m} {s} spp ≥ {g:,} pairs/s" for (m, s), g in GOALS.items())
                      + f"; host time ≤ {GOAL_HOST_MS:g} ms per image; riley-raster ≥ {GOAL_RILEY_EXACT_4:g}× "
                      "slower in exact 4 spp.", "", "How each column is measured: `glsim/bench/throughput.py`.", ""])


def write(report: dict, out) -> str:
    from glsim.bench.report import write_results

    return write_results(report, markdown(report), out, "throughput")
