"""``glsim library``: render a library from a spec, resume one, or verify one.

    glsim library SPEC.toml -o DIR [--workers N | --scheduler tcp://HOST:PORT] [--force] [-q]
    glsim library SPEC.toml --dry-run         # the variant table, estimated time and disk size
    glsim library DIR                         # resume the library in DIR (its stored spec)
    glsim library DIR --verify                # check every file against the manifest
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from glsim.errors import GlsimError

# Rough cost model for --dry-run when no benchmark result is at hand: seconds per megapixel on
# a 2-core llvmpipe machine (GL exact, 1 sample per pixel), and truth bytes per pixel for a
# specimen covering about half the frame (the bulge). A measured bench/results/library.json
# replaces the time figures.
S_PER_MP = {"gl": 0.2, "cpu": 3.0}
TRUTH_S_PER_MP = 1.2
TRUTH_BYTES_PER_PX = {"float64": 3.4, "float32": 1.4}


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


def speedup(workers: int) -> float:
    """Measured end-to-end speed-up of ``workers`` over one (bench/results/library.json), else
    the worker count."""
    try:
        rates = {w["workers"]: w["images_per_s"] for w in json.loads(BENCH.read_text())["workers"]}
        return rates[workers] / rates[1]
    except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
        return float(workers)


BENCH = Path("bench/results/library.json")


def estimate(plan) -> tuple[float, int, str]:
    """(seconds, bytes, where the time figures come from) for rendering ``plan`` on one worker."""
    per_mp, truth_mp, source = dict(S_PER_MP), TRUTH_S_PER_MP, "a 2-core llvmpipe machine (built-in figures)"
    bench = BENCH
    try:
        b = json.loads(bench.read_text())
        mp = b["config"]["width"] * b["config"]["height"] / 1e6
        per_mp["gl"] = b["render_only"]["seconds_per_image"] / mp
        truth_mp = max(b["end_to_end_truth"]["seconds_per_image"] - b["end_to_end_images"]["seconds_per_image"], 0) / mp
        source = f"{bench} ({b['machine']['cpu']}, {b['machine']['gl']['renderer']})"
    except (OSError, ValueError, KeyError, TypeError, ZeroDivisionError):
        pass
    seconds, size = 0.0, 0
    for j in plan.jobs:
        scene = plan.variant(j.variant).scene
        cam = scene.camera(j.camera)
        px = cam.width * cam.height
        r = scene.render
        t = per_mp.get(r.backend, per_mp["gl"]) * px / 1e6 * (1 + 0.85 * (r.samples_per_pixel - 1))
        t *= 1 + 0.33 * sum(x is not None for x in (scene.lighting, scene.optics))
        if j.truth:
            t += truth_mp * px / 1e6
            size += int(TRUTH_BYTES_PER_PX[plan.truth_dtype] * px)
        seconds += t
        size += px * (1 if cam.bit_depth == 8 else 2) + 400
    return seconds, size, source


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.3g} {unit}"
        n /= 1000


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"


def main(argv: list[str] | None = None) -> int:
    from glsim.workflows.library import manifest as mf
    from glsim.workflows.library import runner
    from glsim.workflows.library.spec import expand, load_plan

    args = parser().parse_args(argv)
    src = Path(args.source)
    try:
        if src.is_dir():
            if args.dry_run or args.output:
                raise GlsimError(f"{src} is a library directory: --dry-run and -o take a spec file — give the "
                                 "SPEC.toml, or leave them out to resume this library")
            if args.verify:
                good, problems = runner.verify(src)
                for p in problems[:20]:
                    print(f"bad: {p}")
                if len(problems) > 20:
                    print(f"… and {len(problems) - 20} more")
                print(f"glsim library --verify: {good} images good, {len(problems)} problems in {src}/"
                      + (" — run `glsim library DIR` to re-render them" if problems else ""))
                return 1 if problems else 0
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
            seconds, size, source = estimate(plan)
            seconds, size = seconds * scale, size * scale
            images = round(len(plan.jobs) * scale)
            print(f"{plan.n_variants} variants, {'about ' * plan.sampled}{images} images (cameras "
                  f"{', '.join(plan.cameras)}; steps {', '.join(map(str, plan.steps))}), truth "
                  f"{plan.truth_dtype if plan.truth else 'off'}"
                  + (f"; the {len(plan.variants)} variants shown were checked, the run checks all" * plan.sampled))
            print(_table(plan))
            w = args.workers or runner.default_workers()
            print(f"estimated: {_size(size)} on disk; {_duration(seconds)} on one worker, about "
                  f"{_duration(seconds / max(1.0, speedup(min(w, images))))} with {w} (rough: from {source})")
            print("dry run: nothing was written")
            return 0
        summary = runner.run(plan, out, workers=args.workers, scheduler=args.scheduler, force=args.force,
                             progress=not args.quiet)
    except GlsimError as exc:
        print(f"glsim library: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("glsim library: interrupted — no partial files were left; run the same command again to resume",
              file=sys.stderr)
        return 130
    print(summary.text())
    return 1 if summary.failed else 0
