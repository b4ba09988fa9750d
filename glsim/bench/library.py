"""``glsim bench library``: how fast a library is made, and where the time goes.

Two libraries of the bulge stereo pair (exact mode, 1 sample per pixel) over its 4 load steps,
for at least ``images`` images each:

* **noise**: the noise σ varied between variants — one renderer serves them all and every
  variant shares the truth files of the first (one per camera and step);
* **stereo**: the stereo angle varied (camera 1 turned about the point 600 mm before camera 0,
  which stays put) — camera 1's truth differs per variant, camera 0's is shared.

For each: the render-only rate (the images rendered in this process, nothing encoded or
written; the resident memory sampled along the way), end to end through ``glsim library``
with images only and with compact truth for 1 … ``max_workers`` workers, and once more with
truth on 1 worker with the encoding on a thread of the render process instead of the writer
process (what the writer process buys: the GIL); MB/s, truth files on disk, the stage times
per image summed (serial) against the wall time (their overlap), the peak resident memory.

The ratios to render-only compare runs made minutes apart on a shared machine, so the three
runs they compare (render only, images only, with truth; 1 worker) are repeated ``reps``
times, interleaved, and each counts with its best repetition (its highest rate; every
repetition's rate is kept in the JSON). Render only is timed from its first image on a
warm renderer; an end-to-end run pays its own setup (context, programs, writer process).
"""
from __future__ import annotations

import json
import math
import os
import resource
import shutil
import tempfile
import time
from pathlib import Path

from glsim.bench.report import gl_info, machine_info
from glsim.io import images as io

FULL_SIZE = (1624, 1234)
FULL_IMAGES = 200    # the measured library: 25 variants × 8 images
REPS = 2             # interleaved repetitions of the 1-worker runs (render only, images, truth); the best counts
STEPS = 3            # load steps after the reference: 4 states × 2 cameras = 8 images per variant
LIBRARIES = {"noise": "noise σ", "stereo": "stereo angle"}
DISTANCE = 600.0     # mm: camera 1 stays aimed at the point this far before camera 0


def _spec(size, n_variants: int, truth: bool, kind: str) -> tuple[dict, str]:
    from glsim.scene import bulge_scene
    from glsim.scene.load import from_resolved

    scene, base = from_resolved(json.loads(bulge_scene(size=size, steps=STEPS).to_json()))
    if kind == "noise":
        return {"scene": scene, "truth": truth, "vary": {"noise": {"sigma": [round(0.5 + 0.1 * i, 3)
                                                                              for i in range(n_variants)]}}}, base
    angles = [math.radians(20 + 20 * i / max(n_variants - 1, 1)) for i in range(n_variants)]
    R = [[[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]] for a in angles]
    t = [[-DISTANCE * math.sin(a), 0.0, DISTANCE * (1 - math.cos(a))] for a in angles]
    return {"scene": scene, "truth": truth, "mode": "zip", "vary": {"cameras.1.pose.R": R, "cameras.1.pose.t": t}}, base


def _rss_mb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def _peak_mb() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    kids = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return max(own, kids)


def _render_only(plan) -> dict:
    from glsim.workflows.library import worker

    rss = []
    t_all = time.perf_counter()
    seconds = 0.0
    try:
        first = plan.variants[0].scene
        worker.renderer_for(first).render(plan.jobs[0].camera, plan.jobs[0].step)       # warm-up: context, programs
        t_all = time.perf_counter()
        for k, job in enumerate(plan.jobs):
            r = worker.renderer_for(plan.variant(job.variant).scene)
            t0 = time.perf_counter()
            r.render(job.camera, job.step)
            seconds += time.perf_counter() - t0
            if k % 10 == 0 or k == len(plan.jobs) - 1:
                rss.append(round(_rss_mb(), 1))
    finally:
        worker.release()
    wall = time.perf_counter() - t_all
    n = len(plan.jobs)
    return {"images": n, "seconds": wall, "images_per_s": n / wall, "seconds_per_image": wall / n,
            "render_seconds_per_image": seconds / n, "rss_mb_samples": rss}


class _RSSSampler:
    """This process's resident set every ``period`` s while a run goes on (the 1-worker runs
    render in this process)."""

    def __init__(self, period: float = 0.25):
        import threading
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, args=(period,), daemon=True)

    def _loop(self, period):
        while not self._stop.wait(period):
            self.samples.append(_rss_mb())

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


def _library(plan, workers: int, writer: str = "process") -> dict:
    from glsim.workflows.library import run
    from glsim.workflows.library import writer as writermod

    tmp = Path(tempfile.mkdtemp(prefix="glsim-bench-library-"))
    kind, writermod.KIND = writermod.KIND, writer      # "thread": only the in-process worker follows it
    try:
        with _RSSSampler() as rss:
            s = run(plan, tmp / "lib", workers=workers)
        k = len(rss.samples)
        memory = ({"rss_mb_first_quarter_max": max(rss.samples[:max(1, k // 4)]),
                   "rss_mb_last_quarter_max": max(rss.samples[-max(1, k // 4):]), "rss_mb_max": max(rss.samples)}
                  if workers == 1 and k else {})
        if s.failed:
            raise RuntimeError(f"benchmark library failed: {s.failed[0]}")
        n = s.written
        truths = list((tmp / "lib").rglob("*.truth"))
        per = {"render_s": s.render_s / n, "truth_s": s.truth_s / n, "encode_s": s.encode_s / n,
               "write_s": s.write_s / n}
        return {"workers": workers, "truth": plan.truth, "writer": writer, "images": n, "seconds": s.seconds,
                "images_per_s": n / s.seconds, "seconds_per_image": s.seconds / n,
                "mb_per_s": s.bytes / 1e6 / s.seconds, "truth_files": len(truths),
                "truth_mb_per_image": sum(p.stat().st_size for p in truths) / 1e6 / n,
                "per_image": per, "serial_seconds_per_image": sum(per.values()), "memory": memory}
    finally:
        writermod.KIND = kind
        shutil.rmtree(tmp, ignore_errors=True)


def _best(runs: list[dict]) -> dict:
    """The repetition with the highest rate, with every repetition's rate."""
    best = dict(max(runs, key=lambda x: x["images_per_s"]))
    best["images_per_s_all"] = [x["images_per_s"] for x in runs]
    return best


def bench(size=FULL_SIZE, images: int = FULL_IMAGES, max_workers: int | None = None, reps: int = REPS,
          log=print) -> dict:
    from glsim.render import Renderer
    from glsim.scene import bulge_scene
    from glsim.workflows.library import expand

    per_variant = 2 * (STEPS + 1)
    n_variants = max(1, math.ceil(images / per_variant))
    max_workers = max_workers or os.cpu_count() or 1
    with Renderer(bulge_scene(size=(8, 8), steps=1)) as r:
        machine = machine_info(gl_info(r))
    libraries, rss = {}, []
    for kind in LIBRARIES:
        plans = {truth: expand(*_spec(size, n_variants, truth, kind)) for truth in (False, True)}
        log(f"bench library ({kind}): {len(plans[True].jobs)} images of {size[0]}×{size[1]} ({n_variants} variants of "
            f"the {LIBRARIES[kind]} × 2 cameras × {STEPS + 1} steps)")
        renders, repeated = [], {False: [], True: []}
        for rep in range(reps):
            renders.append(_render_only(plans[False]))
            rss += renders[-1]["rss_mb_samples"]
            log(f"  [{rep + 1}/{reps}] render only: {renders[-1]['images_per_s']:.2f} images/s")
            for truth in (False, True):
                repeated[truth].append(_library(plans[truth], 1))
                log(f"  [{rep + 1}/{reps}] 1 worker, {'with truth' if truth else 'images only'}: "
                    f"{repeated[truth][-1]['images_per_s']:.2f} images/s")
        render = _best(renders)
        runs = [_best(repeated[False]), _best(repeated[True])]
        for w in range(2, max_workers + 1):
            for truth in (False, True):
                runs.append(_library(plans[truth], w))
                log(f"  {w} workers, {'with truth' if truth else 'images only'}: {runs[-1]['images_per_s']:.2f} images/s")
        runs.append(_library(plans[True], 1, writer="thread"))
        log(f"  1 worker, with truth, encoding on a thread: {runs[-1]['images_per_s']:.2f} images/s")
        for run in runs:
            run["ratio_to_render_only"] = run["images_per_s"] / render["images_per_s"]
        libraries[kind] = {"variants": n_variants, "images": len(plans[True].jobs),
                           "truth_keys": len({j.truth for j in plans[True].jobs}), "render_only": render, "runs": runs}
    report = {
        "config": {"width": size[0], "height": size[1], "images": libraries["noise"]["images"], "variants": n_variants,
                   "mode": "exact", "samples_per_pixel": 1, "backend": "gl", "libraries": dict(LIBRARIES),
                   "reps": reps},
        "machine": machine, "date": time.strftime("%Y-%m-%d"), "libraries": libraries,
        "memory": {"render_loop_rss_first_mb": rss[0], "render_loop_rss_last_mb": rss[-1],
                   "render_loop_rss_max_mb": max(rss)},
        "peak_rss_mb": _peak_mb(),
    }
    ratio = lambda kind, truth: _run(report, kind, 1, truth)["ratio_to_render_only"]  # noqa: E731
    noise = libraries["noise"]
    report["goals"] = {
        "images_only_at_least_80pct_of_render_only": min(ratio(k, False) for k in LIBRARIES) >= 0.8,
        "noise_truth_at_least_90pct_of_render_only": ratio("noise", True) >= 0.9,
        "stereo_truth_at_least_60pct_of_render_only": ratio("stereo", True) >= 0.6,
        "noise_truth_disk_divided_by_20": noise["images"] / noise["truth_keys"] >= 20,
    }
    return report


def _run(r: dict, kind: str, workers: int, truth: bool, writer: str = "process") -> dict:
    return next(x for x in r["libraries"][kind]["runs"]
                if (x["workers"], x["truth"], x["writer"]) == (workers, truth, writer))


GOALS = {"images_only_at_least_80pct_of_render_only": "images only end to end ≥ 80 % of the render-only rate "
                                                      "(both libraries, 1 worker)",
         "noise_truth_at_least_90pct_of_render_only": "noise library with truth ≥ 90 %",
         "stereo_truth_at_least_60pct_of_render_only": "stereo library with truth ≥ 60 %",
         "noise_truth_disk_divided_by_20": "the noise library's truth on disk ÷ 20 or better (images per truth file)"}


def markdown(r: dict) -> str:
    c = r["config"]
    full = "" if (c["width"], c["height"]) == FULL_SIZE and c["images"] >= FULL_IMAGES else " (reduced run)"
    return f"# Library benchmark{full}\n\n" + summary(r)


def summary(r: dict) -> str:
    """The tables and their notes (also the generated region of docs/library.md)."""
    c, m = r["config"], r["machine"]
    libs = r["libraries"]
    lines = [f"Bulge stereo pair, {c['width']}×{c['height']}, {c['mode']} mode, {c['samples_per_pixel']} spp, GL; two "
             f"libraries of {c['images']} images ({c['variants']} variants × 2 cameras × 4 load steps): the noise σ "
             f"varied (truth shared by every variant), and the stereo angle, 20–40° (camera 1's truth differs per "
             f"variant). {m['cpu']}, {m['cores']} cores, {m['gl']['renderer']}; {r['date']}.", "",
             "| library | run | workers | images/s | s/image | × render-only | stages s/image | MB/s | truth files | "
             "truth MB/image |", "|---|---|---|---|---|---|---|---|---|---|"]
    for kind, lib in libs.items():
        ro = lib["render_only"]
        lines.append(f"| {kind} | render only (no encoding, no files) | 1 | {ro['images_per_s']:.3g} | "
                     f"{ro['seconds_per_image']:.3g} | 1 | – | – | – | – |")
        for x in lib["runs"]:
            what = ("images + compact truth" if x["truth"] else "images only") + \
                (", encoding on a thread" if x["writer"] == "thread" else "")
            truth = (f"{x['truth_files']} | {x['truth_mb_per_image']:.3g}") if x["truth"] else "– | –"
            lines.append(f"| {kind} | end to end, {what} | {x['workers']} | {x['images_per_s']:.3g} | "
                         f"{x['seconds_per_image']:.3g} | {x['ratio_to_render_only']:.2f} | "
                         f"{x['serial_seconds_per_image']:.3g} | {x['mb_per_s']:.3g} | {truth} |")
    reps = c.get("reps", 1)
    lines += ["", f"Render only and the 1-worker runs with the writer process: the best of {reps} interleaved "
                  "repetitions (every repetition's rate is in library.json); the other runs once each."
              if reps > 1 else "Each run once.", ""]
    for kind in libs:
        pt, th = _run(r, kind, 1, True), _run(r, kind, 1, True, "thread")
        p = pt["per_image"]
        lines.append(f"{kind.capitalize()}, with truth, 1 worker, per image (s): render incl. GL truth read-back "
                     f"{p['render_s']:.3g}, truth encode {p['truth_s']:.3g}, image encode {p['encode_s']:.3g}, write "
                     f"{p['write_s']:.3g} — {pt['serial_seconds_per_image']:.3g} of work in "
                     f"{pt['seconds_per_image']:.3g} wall with the writer process, {th['seconds_per_image']:.3g} with "
                     "the encoding on a thread.")
    mem, tm = r["memory"], _run(r, "noise", 1, True).get("memory") or {}
    lines += [f"Memory: the render loop's resident set {mem['render_loop_rss_first_mb']:.0f} MB after the first image, "
              f"{mem['render_loop_rss_last_mb']:.0f} MB after the last (max {mem['render_loop_rss_max_mb']:.0f}); "
              f"peak of any process {r['peak_rss_mb']:.0f} MB."
              + (f" Noise library with truth, 1 worker: at most {tm['rss_mb_first_quarter_max']:.0f} MB in the first "
                 f"quarter of the run, {tm['rss_mb_last_quarter_max']:.0f} MB in the last." if tm else ""), "",
              "Goals: " + "; ".join(f"{GOALS.get(k, k)}: {'met' if v else 'not met'}{_measured(r, k)}"
                                    for k, v in r["goals"].items()) + "."]
    return "\n".join(lines) + "\n"


def _measured(r: dict, goal: str) -> str:
    """The measured figure behind a goal (a goal missed or met by a hair says so)."""
    libs = r["libraries"]
    if goal == "images_only_at_least_80pct_of_render_only":
        ratios = (f"{k} {_run(r, k, 1, False)['ratio_to_render_only']:.3f}" for k in libs)
        return f" ({', '.join(ratios)})"
    if goal.endswith("render_only"):
        return f" ({_run(r, goal.split('_')[0], 1, True)['ratio_to_render_only']:.3f})"
    if goal == "noise_truth_disk_divided_by_20":
        n = libs["noise"]
        return f" ({n['images']} images, {n['truth_keys']} truth files: ÷ {n['images'] / n['truth_keys']:.3g})"
    return ""


def write(report: dict, out: Path) -> str:
    out.mkdir(parents=True, exist_ok=True)
    io.write_text(out / "library.json", json.dumps(report, indent=2) + "\n")
    text = markdown(report)
    io.write_text(out / "library.md", text)
    return text
