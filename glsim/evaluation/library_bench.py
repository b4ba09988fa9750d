"""``glsim bench library``: how fast a library is made, and where the time goes.

The bulge stereo pair (exact mode, 1 sample per pixel) over its 4 load steps, with the noise σ
varied between variants so that one renderer serves them all (as in a real noise study), for
at least ``images`` images:

* render only: the same images rendered in this process, nothing encoded or written (and the
  resident memory sampled along the way, to show it stays flat);
* end to end, images only, and end to end with compact truth, through ``glsim library`` with
  one worker;
* end to end with truth for 1 … ``max_workers`` workers;
* MB/s written and the peak resident memory of any process.
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

from glsim.evaluation.report import gl_info, machine_info
from glsim.io import images as io

FULL_SIZE = (1624, 1234)
FULL_IMAGES = 100
STEPS = 3            # load steps after the reference: 4 states × 2 cameras = 8 images per variant


def _spec(size, n_variants: int, truth: bool) -> dict:
    from glsim.scene import bulge_scene
    from glsim.scene.load import from_resolved

    scene, base = from_resolved(json.loads(bulge_scene(size=size, steps=STEPS).to_json()))
    sigmas = [round(0.5 + 0.1 * i, 3) for i in range(n_variants)]
    return {"scene": scene, "truth": truth, "vary": {"noise": {"sigma": sigmas}}}, base


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


def _library(plan, workers: int) -> dict:
    from glsim.workflows.library import run

    tmp = Path(tempfile.mkdtemp(prefix="glsim-bench-library-"))
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
        truth_bytes = sum(p.stat().st_size for p in (tmp / "lib").rglob("*.truth"))
        return {"workers": workers, "images": n, "seconds": s.seconds, "images_per_s": n / s.seconds,
                "seconds_per_image": s.seconds / n, "mb_per_s": s.bytes / 1e6 / s.seconds,
                "truth_mb_per_image": truth_bytes / 1e6 / n,
                "per_image": {"render_s": s.render_s / n, "truth_s": s.truth_s / n, "encode_s": s.encode_s / n,
                              "write_s": s.write_s / n}, "memory": memory}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def bench(size=FULL_SIZE, images: int = FULL_IMAGES, max_workers: int | None = None, log=print) -> dict:
    from glsim.render import Renderer
    from glsim.scene import bulge_scene
    from glsim.workflows.library import expand

    per_variant = 2 * (STEPS + 1)
    n_variants = max(1, math.ceil(images / per_variant))
    max_workers = max_workers or os.cpu_count() or 1
    plans = {}
    for truth in (False, True):
        spec, base = _spec(size, n_variants, truth)
        plans[truth] = expand(spec, base)
    with Renderer(bulge_scene(size=(8, 8), steps=1)) as r:
        machine = machine_info(gl_info(r))
    log(f"bench library: {len(plans[True].jobs)} images of {size[0]}×{size[1]} ({n_variants} variants × 2 cameras × "
        f"{STEPS + 1} steps)")
    render = _render_only(plans[False])
    log(f"  render only: {render['images_per_s']:.2f} images/s")
    images_only = _library(plans[False], 1)
    log(f"  end to end, images only: {images_only['images_per_s']:.2f} images/s")
    with_truth = _library(plans[True], 1)
    log(f"  end to end, with truth: {with_truth['images_per_s']:.2f} images/s")
    sweep = [with_truth]
    for w in range(2, max_workers + 1):
        sweep.append(_library(plans[True], w))
        log(f"  {w} workers, with truth: {sweep[-1]['images_per_s']:.2f} images/s")
    rss = render["rss_mb_samples"]
    report = {
        "config": {"width": size[0], "height": size[1], "images": len(plans[True].jobs), "variants": n_variants,
                   "mode": "exact", "samples_per_pixel": 1, "backend": "gl", "varied": "noise.sigma"},
        "machine": machine, "date": time.strftime("%Y-%m-%d"),
        "render_only": render,
        "end_to_end_images": {**images_only, "ratio_to_render_only": images_only["images_per_s"] / render["images_per_s"]},
        "end_to_end_truth": {**with_truth, "ratio_to_render_only": with_truth["images_per_s"] / render["images_per_s"]},
        "workers": [{"workers": s["workers"], "images_per_s": s["images_per_s"], "mb_per_s": s["mb_per_s"]}
                    for s in sweep],
        "memory": {"render_loop_rss_first_mb": rss[0], "render_loop_rss_last_mb": rss[-1],
                   "render_loop_rss_max_mb": max(rss)},
        "peak_rss_mb": _peak_mb(),
    }
    report["goals"] = {
        "images_only_at_least_80pct_of_render_only": report["end_to_end_images"]["ratio_to_render_only"] >= 0.8,
        "truth_at_least_60pct_of_render_only": report["end_to_end_truth"]["ratio_to_render_only"] >= 0.6,
        "truth_at_most_8MB_per_image": with_truth["truth_mb_per_image"] <= 8.0 * (size[0] * size[1]) / (1624 * 1234),
    }
    return report


GOALS = {"images_only_at_least_80pct_of_render_only": "images only end to end ≥ 80 % of the render-only rate",
         "truth_at_least_60pct_of_render_only": "with truth ≥ 60 %",
         "truth_at_most_8MB_per_image": "truth ≤ 8 MB per 1624×1234 image"}


def markdown(r: dict) -> str:
    c = r["config"]
    full = "" if (c["width"], c["height"]) == FULL_SIZE and c["images"] >= FULL_IMAGES else " (reduced run)"
    return f"# Library benchmark{full}\n\n" + summary(r)


def summary(r: dict) -> str:
    """The table and its notes (also the generated region of docs/library.md)."""
    c, m = r["config"], r["machine"]
    ro, ei, et = r["render_only"], r["end_to_end_images"], r["end_to_end_truth"]
    lines = [f"Bulge stereo pair, {c['width']}×{c['height']}, {c['mode']} mode, {c['samples_per_pixel']} spp, GL; "
             f"{c['images']} images ({c['variants']} variants of noise σ × 2 cameras × 4 load steps). "
             f"{m['cpu']}, {m['cores']} cores, {m['gl']['renderer']}; {r['date']}.", "",
             "| run | workers | images/s | s/image | × render-only | MB/s | truth MB/image |",
             "|---|---|---|---|---|---|---|",
             f"| render only (no encoding, no files) | 1 | {ro['images_per_s']:.3g} | {ro['seconds_per_image']:.3g} | 1 | – | – |",
             f"| end to end, images only | 1 | {ei['images_per_s']:.3g} | {ei['seconds_per_image']:.3g} | "
             f"{ei['ratio_to_render_only']:.2f} | {ei['mb_per_s']:.3g} | – |",
             f"| end to end, images + compact truth | 1 | {et['images_per_s']:.3g} | {et['seconds_per_image']:.3g} | "
             f"{et['ratio_to_render_only']:.2f} | {et['mb_per_s']:.3g} | {et['truth_mb_per_image']:.3g} |"]
    for w in r["workers"][1:]:
        lines.append(f"| end to end, images + compact truth | {w['workers']} | {w['images_per_s']:.3g} | "
                     f"{1 / w['images_per_s']:.3g} | {w['images_per_s'] / ro['images_per_s']:.2f} | "
                     f"{w['mb_per_s']:.3g} | {et['truth_mb_per_image']:.3g} |")
    pi, pt = ei["per_image"], et["per_image"]
    mem = r["memory"]
    tm = et.get("memory") or {}
    lines += ["", f"Per image, 1 worker (s): images only — render {pi['render_s']:.3g}, encode {pi['encode_s']:.3g}, "
              f"write {pi['write_s']:.3g}; with truth — render incl. GL truth read-back {pt['render_s']:.3g}, "
              f"truth encode {pt['truth_s']:.3g}, image encode {pt['encode_s']:.3g}, write {pt['write_s']:.3g}.",
              f"Memory: the render loop's resident set {mem['render_loop_rss_first_mb']:.0f} MB after the first image, "
              f"{mem['render_loop_rss_last_mb']:.0f} MB after the last (max {mem['render_loop_rss_max_mb']:.0f}); "
              f"peak of any process {r['peak_rss_mb']:.0f} MB."
              + (f" With truth, 1 worker: at most {tm['rss_mb_first_quarter_max']:.0f} MB in the first quarter of the "
                 f"run, {tm['rss_mb_last_quarter_max']:.0f} MB in the last." if tm else ""), "",
              "Goals: " + "; ".join(f"{GOALS.get(k, k)}: {'met' if v else 'not met'}{_measured(r, k)}"
                                    for k, v in r["goals"].items()) + "."]
    return "\n".join(lines) + "\n"


def _measured(r: dict, goal: str) -> str:
    """The measured ratio behind a rate goal, to 5 decimals (a goal missed or met by a hair says so)."""
    key = {"images_only_at_least_80pct_of_render_only": "end_to_end_images",
           "truth_at_least_60pct_of_render_only": "end_to_end_truth"}.get(goal)
    return f" ({r[key]['ratio_to_render_only']:.5f})" if key else ""


def write(report: dict, out: Path) -> str:
    out.mkdir(parents=True, exist_ok=True)
    io.write_text(out / "library.json", json.dumps(report, indent=2) + "\n")
    text = markdown(report)
    io.write_text(out / "library.md", text)
    return text
