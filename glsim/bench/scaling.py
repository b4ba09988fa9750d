"""`glsim bench scaling`: render time against the element count and the image size.

The scaling plate: a fronto-parallel plate 600 mm in front of camera 0 of the bulge rig,
covering 70 % of the image, meshed ever finer (quad4, 5:4), lens distortion k1 = −0.1, cubic
interpolation, 1 sample per pixel. Per element count (at 1624×1234) and per image size (at a
fixed element count) one fresh process renders it with glsim GL in modes fast, q4 and exact and
with riley-raster (PyPI ``riley-raster``, pyvale's SIMD CPU rasteriser: the same mesh and
camera, Catmull–Rom cubic) when installed, interleaved: each repetition renders once with every
renderer in turn, and the median per renderer is reported. Also per glsim mode: the host
("CPU side") time per render — the calling thread's CPU time less its read-back waits
(:func:`glsim.backends.gl.timing.driver_time`, as the throughput benchmark counts it): Python,
numpy and the driver's work on that thread. On llvmpipe that includes Mesa's vertex stage, which
runs on the calling thread, so the fast mode's (every element's triangles drawn) grows with the
element count; q4 and exact place elements in compute passes, which llvmpipe runs on its own
threads. Wall time less waits is not used: llvmpipe finishes the frame inside the read-back's
submission, outside any wait glsim can name. Also the first render (uploads and shader builds included), the
process's peak resident memory and the bytes of the mesh's GL buffers. Optionally the float64
CPU oracle (exact mode, one render) in its own process, with its peak memory.

Then, per point and mode, one more render timed pass by pass (each draw and dispatch between
two ``finish`` calls, :meth:`GLBackend.pass_times`): where the time goes as the mesh grows.

Writes ``scaling.json`` and ``scaling.md``; only the full run writes to bench/results.
"""
from __future__ import annotations

import datetime
import math
import multiprocessing
import statistics
import sys
import time
import traceback

import numpy as np

from glsim.bench.accuracy import PLATE_FILL, PLATE_TEXTURE_PX, plate_geometry, riley_setup
from glsim.bench.formatting import num
from glsim.scene import Plate, Render, Scene, Specimen, Speckle, stereo_rig
from glsim.scene.camera import Distortion

FULL_SIZE = (1624, 1234)
FULL_ELEMENTS = (2_000, 8_000, 32_000, 128_000, 512_000, 1_000_000)
FULL_SIZES = ((816, 620), (1624, 1234), (2448, 1860), (3264, 2480))   # 0.5, 2.0, 4.6, 8.1 Mpx
SIZE_ELEMENTS = 128_000     # the element count of the image-size sweep
REPS = 5
MODES = ("fast", "q4", "exact")
K1 = -0.1
GOAL_ELEMENTS = 128_000     # the scaling goals: no slower than riley-raster at this count …
GOAL_HOST_MS = 5.0          # … and the host time per render at any count


def plate_layout(n: int) -> tuple[int, int]:
    """Elements along x and y (5:4) for about n elements."""
    ny = max(1, round(math.sqrt(n * 4 / 5)))
    return max(1, round(n / ny)), ny


def plate_scene(size: tuple[int, int], n: int) -> Scene:
    """Camera 0 of the bulge rig with k1 = K1, the plate meshed with about n quad4 elements."""
    g = plate_geometry(size)
    nx, ny = plate_layout(n)
    cam = stereo_rig(size=size, fx=g["fx"], distortion=Distortion(k1=K1))[0]
    return Scene(cameras=(cam,), specimen=Specimen(plate=Plate(width=g["width"], height=g["height"], nx=nx, ny=ny),
                                                   t=(0.0, 0.0, g["distance"])),
                 speckle=Speckle(mm_per_px=g["width"] / PLATE_TEXTURE_PX), render=Render(interpolation="cubic"))


def riley_render(size: tuple[int, int], n: int):
    """A callable rendering the same plate with riley-raster (quad4, k1, Catmull–Rom cubic, 1
    sample per pixel), or None with the reason when riley is not installed."""
    try:
        import riley
    except ImportError:
        return None, "not installed"
    mesh, camera, config = riley_setup(size, *plate_layout(n), sub_sample=1, k1=K1)
    from importlib.metadata import version
    return (lambda: np.squeeze(riley.raster(mesh, camera, config))), f"riley-raster {version('riley-raster')}"


def _peak_rss_mb() -> float:
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(size: tuple[int, int], n: int, reps: int) -> dict:
    """One point, in the calling process: glsim GL fast/q4/exact and riley interleaved."""
    from glsim.backends.gl.timing import driver_time
    from glsim.bench.report import gl_info, machine_info
    from glsim.render import Renderer

    t0 = time.perf_counter()
    scene = plate_scene(size, n)
    renderer = Renderer(scene, "gl")
    M = len(renderer.mesh.quads)
    setup = time.perf_counter() - t0
    rows = {}
    calls = {}
    for mode in MODES:
        t = time.perf_counter()
        res = renderer.render(0, 0, mode=mode)
        rows[mode] = {"first_s": time.perf_counter() - t, "seconds": [], "host_ms": [],
                      "coverage": float(np.mean(res.image != scene.render.background))}

        def call(mode=mode):
            with driver_time() as d:
                t, c = time.perf_counter(), time.thread_time()
                renderer.render(0, 0, mode=mode)
                wall, cpu = time.perf_counter() - t, time.thread_time() - c
            rows[mode]["seconds"].append(wall)
            rows[mode]["host_ms"].append(d.host_seconds(wall, cpu)[1] * 1e3)
        calls[mode] = call
    riley_call, riley_name = riley_render(size, n)
    if riley_call is not None:
        t = time.perf_counter()
        image = riley_call()
        rows["riley"] = {"first_s": time.perf_counter() - t, "seconds": [], "name": riley_name,
                         "coverage": float(np.mean(image != 0))}

        def timed_riley():
            t = time.perf_counter()
            riley_call()
            rows["riley"]["seconds"].append(time.perf_counter() - t)
        calls = {"riley": timed_riley, **calls}
    for _ in range(reps):                     # interleaved: every renderer once per repetition
        for call in calls.values():
            call()
    for mode in MODES:                        # then one render per mode, pass by pass
        with renderer.backend.pass_times() as p:
            t = time.perf_counter()
            renderer.render(0, 0, mode=mode)
            rows[mode]["passes_wall_s"] = time.perf_counter() - t
        rows[mode]["passes"] = p
    gl_bytes = renderer.backend.geometry.buffer_bytes()
    out = {"size": list(size), "elements": M, "setup_s": setup, "gl_buffer_mb": gl_bytes / 2 ** 20,
           "machine": machine_info(gl_info(renderer)), "renderers": {}}
    renderer.close()
    for name, r in rows.items():
        out["renderers"][name] = {k: v for k, v in r.items() if k not in ("seconds", "host_ms")}
        out["renderers"][name]["median_s"] = statistics.median(r["seconds"])
        out["renderers"][name]["all_s"] = r["seconds"]
        if "host_ms" in r:
            out["renderers"][name]["host_ms"] = statistics.median(r["host_ms"])
            out["renderers"][name]["host_ms_max"] = max(r["host_ms"])
    if riley_call is None:
        out["renderers"]["riley"] = {"name": "riley-raster", "status": riley_name}
    out["peak_rss_mb"] = _peak_rss_mb()
    return out


def measure_oracle(size: tuple[int, int], n: int) -> dict:
    """The CPU oracle (exact, float64) on the same plate: one render, its time and peak memory."""
    from glsim.render import Renderer

    scene = plate_scene(size, n)
    with Renderer(scene, "cpu") as r:
        t = time.perf_counter()
        r.render(0, 0, mode="exact")
        seconds = time.perf_counter() - t
        M = len(r.mesh.quads)
    return {"size": list(size), "elements": M, "seconds": seconds, "peak_rss_mb": _peak_rss_mb()}


def _child(conn, fn, args):
    try:
        conn.send(("ok", fn(*args)))
    except BaseException as exc:  # reported in the results, the run goes on
        conn.send(("failed", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=3)}"))
    finally:
        conn.close()


def in_process(fn, *args, timeout: float = 3600.0) -> dict:
    """Run ``fn(*args)`` in a fresh process (its own GL context; its own peak memory)."""
    ctx = multiprocessing.get_context("spawn")
    parent, child = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(child, fn, args))
    p.start()
    child.close()
    try:
        if parent.poll(timeout):
            status, value = parent.recv()
        else:
            status, value = "failed", f"no result within {timeout:.0f} s"
    except EOFError:
        status, value = "failed", "the process ended without a result (out of memory?)"
    p.join(timeout=60)
    if p.is_alive():
        p.kill()
    code = p.exitcode
    if status == "ok":
        return value
    return {"status": "failed", "error": value if code in (0, None) else f"{value} (exit code {code})",
            "args": [list(a) if isinstance(a, tuple) else a for a in args]}


def scaling(elements=FULL_ELEMENTS, sizes=FULL_SIZES, size_elements=SIZE_ELEMENTS, reps=REPS, oracle=True,
            log=print) -> dict:
    """Every point in its own process: element counts at FULL_SIZE, then image sizes at
    ``size_elements``; the oracle (if asked) per element count."""
    report = {"date": datetime.date.today().isoformat(), "reps": reps, "k1": K1, "fill": PLATE_FILL,
              "elements": [], "sizes": [], "oracle": []}
    for n in elements:
        t = time.perf_counter()
        report["elements"].append(in_process(measure, FULL_SIZE, n, reps))
        log(f"glsim bench scaling: {n} elements at {FULL_SIZE[0]}×{FULL_SIZE[1]} ({time.perf_counter() - t:.0f} s)")
    for size in sizes:
        t = time.perf_counter()
        report["sizes"].append(in_process(measure, tuple(size), size_elements, reps))
        log(f"glsim bench scaling: {size[0]}×{size[1]} px, {size_elements} elements ({time.perf_counter() - t:.0f} s)")
    if oracle:
        for n in elements:
            t = time.perf_counter()
            report["oracle"].append(in_process(measure_oracle, FULL_SIZE, n))
            log(f"glsim bench scaling: oracle, {n} elements ({time.perf_counter() - t:.0f} s)")
    ok = [r for r in report["elements"] + report["sizes"] if "renderers" in r]
    report["machine"] = ok[0]["machine"] if ok else None
    report["goals"] = goals(report)
    return report


# ---- report ------------------------------------------------------------------------------------
def _median_s(r: dict, name: str):
    x = r.get("renderers", {}).get(name, {})
    return x.get("median_s")


def goals(report: dict) -> list[dict]:
    """The scaling goals on this run's points (None where the run did not measure them): fast and exact
    no slower than riley-raster at GOAL_ELEMENTS, exact there within 2× its time at 2,000, host time
    below GOAL_HOST_MS."""
    pts = {r["elements"]: r for r in report["elements"] if "renderers" in r}

    def near(target):  # the measured count within 5 % of target (plates round it), else None
        m = min(pts, key=lambda m: abs(m - target)) if pts else None
        return m if m is not None and abs(m - target) <= 0.05 * target else None

    g128, g2 = near(GOAL_ELEMENTS), near(2_000)
    out = []
    for mode in ("exact", "fast"):
        riley, mine = (_median_s(pts[g128], "riley"), _median_s(pts[g128], mode)) if g128 else (None, None)
        out.append({"goal": f"{mode} at {GOAL_ELEMENTS:,} elements no slower than riley-raster",
                    "measured": None if not (riley and mine) else f"{mine:.3g} s vs {riley:.3g} s ({mine / riley:.2f}×) "
                    f"at {pts[g128]['elements']:,} elements",
                    "met": None if not (riley and mine) else mine <= riley})
    a, b = (_median_s(pts[g128], "exact"), _median_s(pts[g2], "exact")) if g128 and g2 else (None, None)
    out.append({"goal": f"exact at {GOAL_ELEMENTS:,} elements within 2× its time at 2,000",
                "measured": None if not (a and b) else f"{a:.3g} s vs {b:.3g} s ({a / b:.2f}×)",
                "met": None if not (a and b) else a <= 2 * b})
    # the element-count sweep (one image size); the size sweep shows what grows with the pixels
    host = [(r["elements"], m, r["renderers"][m]["host_ms"]) for r in report["elements"]
            if "renderers" in r for m in MODES if "host_ms" in r["renderers"].get(m, {})]
    worst = max(host, key=lambda h: h[2]) if host else None
    out.append({"goal": f"host (CPU-side) time per render below {GOAL_HOST_MS:g} ms at any element count",
                "measured": None if not worst else f"median at most {worst[2]:.2f} ms ({worst[1]}, {worst[0]:,} elements, "
                f"{FULL_SIZE[0]}×{FULL_SIZE[1]})", "met": None if not worst else worst[2] < GOAL_HOST_MS})
    return out


def _row(r: dict, first: str) -> str:
    if "renderers" not in r:
        return f"| {first} | failed: {r.get('error', '?').splitlines()[0]} |||||||||"
    rl = _median_s(r, "riley")
    cells = [first, f"{r['elements']:,}", num(rl)]
    for m in MODES:
        cells.append(num(_median_s(r, m)))
    for m in ("fast", "exact"):
        x = _median_s(r, m)
        cells.append("–" if not (x and rl) else f"{x / rl:.2f}")
    cells.append(" / ".join(num(r["renderers"][m].get("host_ms"), ".2g") for m in MODES))
    cells.append(f"{r['peak_rss_mb']:.0f}")
    cells.append(f"{r['gl_buffer_mb']:.0f}")
    return "| " + " | ".join(cells) + " |"


HEADER = ("| {first} | elements | riley (s) | fast (s) | q4 (s) | exact (s) | fast / riley | exact / riley | "
          "host ms per render (fast / q4 / exact) | peak RSS (MB) | mesh GL buffers (MB) |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|")


def markdown(report: dict) -> str:
    m = report.get("machine") or {}
    gl = m.get("gl", {})
    riley = next((r["renderers"]["riley"].get("name") for r in report["elements"] + report["sizes"]
                  if "renderers" in r and "riley" in r["renderers"]), "riley-raster")
    lines = ["# glsim scaling benchmark", "",
             f"{report['date']}, {m.get('cpu', '?')}, {m.get('cores', '?')} cores, {gl.get('renderer', '?')}. "
             f"Fronto-parallel quad4 plate covering {report['fill']:.0%} of the image, k1 = {report['k1']}, cubic, "
             f"1 sample per pixel; glsim GL and {riley} interleaved in one process per point, median of "
             f"{report['reps']} renders each. Host ms: the calling thread's CPU time per render less its "
             "read-back waits (Python, numpy and the driver's work on that thread — on llvmpipe Mesa's vertex "
             "stage too, which the fast mode feeds every element's triangles). Peak RSS: the process (glsim and "
             "riley together).", "",
             "## Goals", "", "| goal | measured | met |", "|---|---|---|"]
    for g in report["goals"]:
        met = "not measured" if g["met"] is None else ("yes" if g["met"] else "no")
        lines.append(f"| {g['goal']} | {g['measured'] or '–'} | {met} |")
    lines += ["", f"## Element count ({FULL_SIZE[0]}×{FULL_SIZE[1]})", "", HEADER.format(first="point")]
    lines += [_row(r, f"{r['elements']:,}" if "elements" in r else "?") for r in report["elements"]]
    lines += ["", f"## Image size ({report['sizes'][0]['elements']:,} elements)" if report["sizes"] and
              "elements" in report["sizes"][0] else "## Image size", "", HEADER.format(first="size")]
    lines += [_row(r, f"{r['size'][0]}×{r['size'][1]} ({r['size'][0] * r['size'][1] / 1e6:.1f} Mpx)"
                   if "size" in r else "?") for r in report["sizes"]]
    lines += ["", "## Where the time goes (exact, one render timed pass by pass)", "", PASSES_NOTE, "",
              passes_table(report["elements"], "exact")]
    if report["oracle"]:
        lines += ["", "## CPU oracle (exact, float64, one render)", "",
                  "| elements | time (s) | peak RSS (MB) |", "|---|---|---|"]
        for r in report["oracle"]:
            lines.append(f"| {r['elements']:,} | {r['seconds']:.3g} | {r['peak_rss_mb']:.0f} |" if "seconds" in r
                         else f"| {r.get('args', ['?', '?'])[1]} | failed: {r['error'].splitlines()[0]} | |")
    return "\n".join(lines) + "\n"


PASSES_NOTE = ("Each draw or dispatch between two `finish` calls (ms), named by its shader; \"rest\": that "
               "render's wall time less its passes (read-back, clears, Python). Their sum exceeds a pipelined "
               "render's time a little.")


def passes_table(points: list[dict], mode: str) -> str:
    """Where ``mode``'s time goes per element count: each pass's seconds (ms) from the render
    timed pass by pass, the rest of that render (read-back, clears, host) and its wall time."""
    pts = [r for r in points if "passes" in r.get("renderers", {}).get(mode, {})]
    names = list(dict.fromkeys(n for r in pts for n in r["renderers"][mode]["passes"]))
    lines = ["| elements | " + " | ".join(f"`{n}`" for n in names) + " | rest | wall |",
             "|---|" + "---|" * (len(names) + 2)]
    for r in pts:
        row = r["renderers"][mode]
        ms = [row["passes"].get(n) for n in names]
        rest = row["passes_wall_s"] - sum(x for x in ms if x)
        lines.append(f"| {r['elements']:,} | " + " | ".join("–" if x is None else f"{1e3 * x:.1f}" for x in ms)
                     + f" | {1e3 * rest:.1f} | {1e3 * row['passes_wall_s']:.1f} |")
    return "\n".join(lines)


def rewrite(path) -> str:
    """Goals and markdown again from a scaling.json (after a change to the report only)."""
    import json
    from pathlib import Path

    path = Path(path)
    report = json.loads(path.read_text())
    report["goals"] = goals(report)
    return write(report, path.parent)


def write(report: dict, out) -> str:
    """scaling.json and scaling.md into ``out``; returns the markdown."""
    from glsim.bench.report import write_results
    return write_results(report, markdown(report), out, "scaling")


if __name__ == "__main__":  # pragma: no cover - a single point, for profiling
    print(measure(FULL_SIZE, int(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 3))
