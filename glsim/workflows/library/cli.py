"""glsim library: render a library from a spec, resume one, or verify one.

    glsim library SPEC.toml -o DIR [--workers N | --scheduler tcp://HOST:PORT] [--force] [-q]
    glsim library SPEC.toml --dry-run         # the variant table, estimated time and disk size
    glsim library DIR                         # resume the library in DIR (its stored spec)
    glsim library DIR --verify                # check every file against the manifest

A spec with a [training] table writes a training set instead: WebDataset shards of image pairs
and their labels (docs/training.md); DIR and --verify work the same on it.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from glsim.io.hashes import sha256_bytes
from glsim.errors import GlsimError, interrupted


def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="glsim library", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("source", help="a library spec (TOML), or a library directory to resume or --verify")
    ap.add_argument("-o", "--output", help="library directory (with a spec; default: the spec's name without .toml)")
    ap.add_argument("--workers", type=int, default=None,
                    help="local worker processes (default: one per GPU EGL lists, else one per core)")
    ap.add_argument("--scheduler", help="run on a Dask distributed cluster: tcp://HOST:PORT of its scheduler "
                    "(start workers with --nthreads 1; DIR must be on a filesystem every worker can write)")
    ap.add_argument("--dry-run", action="store_true", help="print the variants and the estimated time and disk "
                    "size; write nothing")
    ap.add_argument("--verify", action="store_true", help="check every file of the library DIR against its manifest")
    ap.add_argument("--force", action="store_true", help="replace a library of another spec in DIR")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    return ap


TABLE_ROWS = 40   # --dry-run's table: the first 35 variants and the last 5 (only those are built and checked)


def _table(plan, limit: int = TABLE_ROWS) -> str:
    head = ["variant", *plan.keys, "images"]
    counts: dict[str, int] = {}
    for j in plan.jobs:
        counts[j.variant] = counts.get(j.variant, 0) + 1
    rows = [[v.id, *(_cell(v.params[k]) for k in plan.keys), str(counts.get(v.id, 0))] for v in plan.variants]
    gap = len(rows) > limit or plan.sampled
    shown = rows[:limit - 5] + [["…"] * len(head)] + rows[-5:] if gap else rows
    width = [max(len(r[i]) for r in [head] + shown) for i in range(len(head))]
    line = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, width)).rstrip()  # noqa: E731
    return "\n".join([line(head)] + [line(r) for r in shown])


def _cell(value) -> str:
    """A parameter as the table shows it, with its type: 1.0 stays 1.0 (6 significant digits)."""
    if not isinstance(value, float):
        return json.dumps(value)
    text = f"{value:.6g}"
    return text if any(c in text for c in ".eni") else text + ".0"


def measure(plan) -> dict:
    """The spec's first image, measured on this machine (seconds, bytes): its variant's renderer
    made and the image rendered once (``setup_s``: context, reference image, programs), then
    rendered again without truth (``render_s``) and with it (``truth_render_s``: the extra),
    the image encoded (``encode_s``, ``image_bytes``) and its truth (``truth_encode_s``,
    ``truth_bytes``) as the writer does."""
    import time
    import warnings

    from glsim.io import truthcodec
    from glsim.workflows.library import worker, writer

    job = plan.jobs[0]
    scene = plan.variant(job.variant).scene
    clock = time.perf_counter
    m = {"job": job, "truth_render_s": 0.0, "truth_encode_s": 0.0, "truth_bytes": 0}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # the run warns where it matters
            t0 = clock()
            r = worker.renderer_for(scene)
            r.render(job.camera, job.step)
            t1 = clock()
            res = r.render(job.camera, job.step)
            t2 = clock()
            data = writer.image_bytes(res.image, res.camera.bit_depth, scene.output.format)
            sha256_bytes(data)
            m.update(setup_s=t1 - t0, render_s=t2 - t1, encode_s=clock() - t2, image_bytes=len(data))
            if plan.truth:
                t0 = clock()
                t = r.render(job.camera, job.step, truth=True).truth
                t1 = clock()
                tdata = truthcodec.encode_compact(t.element, t.xi, t.eta, {}, plan.truth_dtype)
                m.update(truth_render_s=max(t1 - t0 - m["render_s"], 0.0), truth_encode_s=clock() - t1,
                         truth_bytes=len(tdata))
    finally:
        worker.release()
    return m


def estimate(plan, m: dict) -> tuple[float, int]:
    """(seconds on one worker, bytes) of ``plan`` from :func:`measure`'s figures ``m``, scaled
    by each image's pixels × samples per pixel: per image the render and, beside it in the
    writer process, the encoding (the longer of the two counts); the truth's render and encoding
    once per truth file; the set-up once per new reference image (a renderer change)."""
    from glsim.workflows.library.keys import reference_key

    first = plan.variant(m["job"].variant).scene
    cam0 = first.camera(m["job"].camera)
    unit = cam0.width * cam0.height
    seconds, size, truths, refs, last = 0.0, 0, set(), {}, None
    for j in plan.jobs:
        scene = plan.variant(j.variant).scene
        cam = scene.camera(j.camera)
        px = cam.width * cam.height / unit
        k = px * scene.render.samples_per_pixel / first.render.samples_per_pixel
        if j.variant not in refs:
            refs[j.variant] = reference_key(scene, scene.render.backend)
        if refs[j.variant] != last:
            seconds, last = seconds + m["setup_s"], refs[j.variant]
        render, encode = m["render_s"] * k, m["encode_s"] * k
        if j.truth and j.truth not in truths:
            truths.add(j.truth)
            render, encode = render + m["truth_render_s"] * k, encode + m["truth_encode_s"] * k
            size += int(m["truth_bytes"] * px)
        seconds += max(render, encode)
        size += int(m["image_bytes"] * px)
    return seconds, size


def _estimate_line(plan, scale: float, workers: int) -> str:
    """The dry run's estimate, from the first image measured here (:func:`measure`), or why not."""
    from glsim.workflows.library.worker import gpus

    try:
        m = measure(plan)
    except (GlsimError, RuntimeError, OSError, ValueError) as exc:
        return f"estimated: not measured — the first image did not render here ({type(exc).__name__}: {exc})"
    seconds, size = (x * scale for x in estimate(plan, m))
    j, g = m["job"], len(gpus())
    truth = (f", +{m['truth_render_s']:.3g} s with truth, encoded in {m['truth_encode_s']:.3g} s (once per truth "
             f"file: {len({job.truth for job in plan.jobs}) * scale:.0f})") if plan.truth else ""
    more = ("" if workers == 1 else f"; about {_duration(seconds / min(workers, g))} with {workers} workers on {g} GPUs"
            if g > 1 else f"; {workers} workers share {'one GPU' if g else 'the cores llvmpipe renders on'}: "
            "expect little gain")
    return (f"estimated: {_size(size)} on disk; {_duration(seconds)} on one worker{more} (measured here: {j.variant} "
            f"{j.camera} step {j.step} renders in {m['render_s']:.3g} s{truth}; the image is encoded in "
            f"{m['encode_s']:.3g} s beside the next render; set-up {m['setup_s']:.3g} s per new reference image)")


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.3g} {unit}"
        n /= 1000


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"


def main(argv: list[str] | None = None) -> int:
    from glsim.workflows.library import manifest as mf
    from glsim.workflows.library import audit, runner
    from glsim.workflows.library.spec import expand, load_plan

    args = parser().parse_args(argv)
    src = Path(args.source)
    try:
        if args.workers is not None and args.workers < 1:    # (refused before anything is read or written)
            raise GlsimError(f"--workers {args.workers}: must be ≥ 1 — give the number of worker processes")
        from glsim.workflows.training import cli as training_cli
        if training_cli.handles(src):      # a spec with [training], or a training set: shards (docs/training.md)
            return training_cli.main(args)
        if src.is_dir():
            if args.dry_run or args.output:
                raise GlsimError(f"{src} is a library directory: --dry-run and -o take a spec file — give the "
                                 "SPEC.toml, or leave them out to resume this library")
            if args.verify:
                good, problems = audit.verify(src)
                return audit.print_verify(good, problems, "images", src, "run `glsim library DIR` to re-render them")
            info = mf.read_library_info(src)
            if info is None:
                raise GlsimError(f"{src}: holds no library (no library.json, or a damaged one) — give a spec file, or a "
                                 "directory that `glsim library SPEC -o DIR` wrote")
            plan = expand(info["spec"], info["base_dir"])
            out = src
        else:
            if args.verify:
                raise GlsimError(f"--verify checks a library directory, and {src} is not one — give the DIR the "
                                 "library was written to")
            plan = load_plan(src, sample=TABLE_ROWS if args.dry_run else None)
            out = Path(args.output) if args.output else src.with_suffix("")
        if args.dry_run:
            scale = plan.n_variants / len(plan.variants)     # > 1: only the tabulated variants were built
            images = round(len(plan.jobs) * scale)
            print(f"{plan.n_variants} variants, {'about ' * plan.sampled}{images} images (cameras "
                  f"{', '.join(plan.cameras)}; steps {', '.join(map(str, plan.steps))}), truth "
                  f"{plan.truth_dtype if plan.truth else 'off'}"
                  + (f"; the {len(plan.variants)} variants shown were checked, the run checks all" * plan.sampled))
            print(_table(plan))
            print(_estimate_line(plan, scale, args.workers or runner.default_workers()))
            print("dry run: nothing was written")
            return 0
        summary = runner.run(plan, out, workers=args.workers, scheduler=args.scheduler, force=args.force,
                             progress=not args.quiet)
    except GlsimError as exc:
        print(f"glsim library: error: {exc}", file=sys.stderr)
        return 2
    except BaseException as exc:
        if not interrupted(exc):
            raise
        print("glsim library: interrupted — no partial files were left; run the same command again to resume",
              file=sys.stderr)
        return 130
    print(summary.text())
    return 1 if summary.failed else 0
