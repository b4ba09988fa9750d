"""``glsim bench {accuracy,effects,library,preview,scaling,quadratic,peer,throughput,jacobian,training}``: what
accuracy costs on this machine, each bench writing NAME.json and NAME.md.

Committed results live in ``bench/results``; only a full-size run writes there by default. A
quick or reduced run writes to ``build/bench`` unless ``--out`` names another directory, and is
refused with ``--out bench/results``, so the committed figures change only by a full run.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from glsim.errors import GLUnavailableError, GlsimError
from glsim.io import images as io

RESULTS = Path("bench/results")      # committed results (full runs only)
SCRATCH = Path("build/bench")        # quick and reduced runs


def results_dir(out: str | None, full: bool, command: str) -> Path:
    """Where a benchmark writes: ``--out`` if given, else bench/results for a full run and
    build/bench otherwise; a reduced run aimed at the committed results is refused."""
    if out is None:
        return RESULTS if full else SCRATCH
    if not full and Path(out).resolve() == RESULTS.resolve():
        raise GlsimError(f"--out {out}: a quick or reduced `glsim bench {command}` would overwrite the committed "
                         f"full-size results; leave out --out (it writes to {SCRATCH}) or run at full size")
    return Path(out)


def main(argv: list[str]) -> int:
    """``glsim bench accuracy [--size W H] [--reps N] [--out DIR] [--quick]``, ``glsim bench
    effects …`` and ``glsim bench library [--size W H] [--images N] [--max-workers N]``; returns
    the exit status."""
    from glsim.bench import accuracy, effects

    parser = argparse.ArgumentParser(prog="glsim bench")
    sub = parser.add_subparsers(dest="command", required=True)
    acc = sub.add_parser("accuracy", help="time and accuracy of every mode against the CPU oracle")
    acc.add_argument("--size", nargs=2, type=int, metavar=("W", "H"),
                     help="image size in px (default 1624 1234; with --quick 406 308)")
    acc.add_argument("--reps", type=int, default=5, help="timed renders per row after one warm-up (default 5)")
    acc.add_argument("--quick", action="store_true", help="small image and fewer combinations (CI smoke test)")
    eff = sub.add_parser("effects", help="time per image of each optical effect, GL and CPU")
    eff.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), help="image size (default 1624 1234)")
    eff.add_argument("--reps", type=int, default=5, help="timed renders per camera (default 5; CPU at most 2)")
    eff.add_argument("--only", choices=effects.ONLY, help="run only the camera-effect or the motion rows and merge "
                     "them into the effects.json there (its other rows kept)")
    lib = sub.add_parser("library", help="library images/s: render only vs end to end, workers 1…N, memory")
    lib.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), help="image size (default 1624 1234)")
    lib.add_argument("--images", type=int, default=200, help="images per run (default 200; the full run needs ≥ 200)")
    lib.add_argument("--max-workers", type=int, default=None, help="largest worker count (default: one per core)")
    lib.add_argument("--reps", type=int, default=2, help="interleaved repetitions of the 1-worker runs (default 2)")
    from glsim.bench import preview as pb
    pre = sub.add_parser("preview", help="frame times of the interactive preview (dragging, refinement)")
    pre.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), help="camera size (default 1624 1234)")
    pre.add_argument("--reps", type=int, default=30, help="dragged frames per case (default 30)")
    pre.add_argument("--frame", nargs=2, type=int, default=pb.FRAME, metavar=("W", "H"), help="preview frame size")
    pre.add_argument("--drag-width", type=int, default=pb.DRAG_WIDTH, help="camera width rendered while dragging")
    pre.add_argument("--out", default=None, help=f"directory of preview.json / preview.md (default {RESULTS} for a "
                     f"full run, {SCRATCH} otherwise)")
    from glsim.bench import scaling
    sca = sub.add_parser("scaling", help="time against element count and image size, GL modes and riley-raster")
    sca.add_argument("--elements", type=int, nargs="+", metavar="N",
                     help=f"element counts at 1624×1234 (default {' '.join(map(str, scaling.FULL_ELEMENTS))})")
    sca.add_argument("--sizes", nargs="+", metavar="WxH",
                     help="image sizes of the size sweep (default " + " ".join(f"{w}x{h}" for w, h in scaling.FULL_SIZES)
                     + "; none: --sizes 0)")
    sca.add_argument("--size-elements", type=int, default=scaling.SIZE_ELEMENTS,
                     help=f"element count of the size sweep (default {scaling.SIZE_ELEMENTS})")
    sca.add_argument("--reps", type=int, default=scaling.REPS, help=f"interleaved repetitions (default {scaling.REPS})")
    sca.add_argument("--no-oracle", action="store_true", help="leave out the CPU oracle's rows")
    sca.set_defaults(size=None)
    from glsim.bench import quadratic
    qua = sub.add_parser("quadratic", help="quadratic elements (Q8, T6): mapping error and time per backend and "
                         "mode against a closed form")
    qua.add_argument("--size", nargs=2, type=int, metavar=("W", "H"),
                     help=f"image size (default {quadratic.FULL_SIZE[0]} {quadratic.FULL_SIZE[1]})")
    qua.set_defaults(reps=1)
    from glsim.bench import peer
    pee = sub.add_parser("peer", help="riley-raster against glsim GL on one plate (k1 0 and -0.1, cubic, 4 spp): "
                         "interleaved times, mapping and grey error against the CPU oracle")
    pee.add_argument("--size", nargs=2, type=int, metavar=("W", "H"),
                     help=f"image size (default {peer.FULL_SIZE[0]} {peer.FULL_SIZE[1]}; with --quick "
                     f"{peer.QUICK_SIZE[0]} {peer.QUICK_SIZE[1]})")
    pee.add_argument("--reps", type=int, default=None,
                     help=f"interleaved repetitions after one warm-up (default {peer.REPS}; with --quick 3)")
    pee.add_argument("--quick", action="store_true", help="half size, 3 repetitions (writes to build/bench)")
    from glsim.bench import throughput as tp
    thr = sub.add_parser("throughput", help="stereo pairs/s delivered as 8-bit images, one at a time and pipelined, "
                         "fast/q4/exact × 1/4/16 spp, with riley-raster")
    thr.add_argument("--size", nargs=2, type=int, metavar=("W", "H"),
                     help=f"image size (default {tp.FULL_SIZE[0]} {tp.FULL_SIZE[1]}; with --quick "
                     f"{tp.QUICK_SIZE[0]} {tp.QUICK_SIZE[1]})")
    thr.add_argument("--reps", type=int, default=tp.REPS, help=f"interleaved repetitions (default {tp.REPS})")
    thr.add_argument("--pairs", type=int, default=tp.PAIRS, help=f"stereo pairs per way and repetition "
                     f"(default {tp.PAIRS})")
    thr.add_argument("--quick", action="store_true", help="quarter size, 1 and 4 spp, 2,000 elements, 1 pair, 1 repetition "
                     "(writes to build/bench)")
    from glsim.bench import jacobian as jbm
    jb = sub.add_parser("jacobian", help="time of an image Jacobian against one render and finite differences")
    jb.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), help=f"image size (default {jbm.FULL_SIZE[0]} "
                    f"{jbm.FULL_SIZE[1]}; with --quick {jbm.QUICK_SIZE[0]} {jbm.QUICK_SIZE[1]})")
    jb.add_argument("--reps", type=int, default=3, help="interleaved repetitions after one warm-up (default 3)")
    jb.add_argument("--quick", action="store_true", help="quarter size (writes to build/bench)")
    from glsim.bench import training as trb
    tra = sub.add_parser("training", help="pairs/s delivered into training shards: 2-D 256² (1 and 2 workers) and "
                         "stereo 1 Mpx, peak memory")
    tra.add_argument("--pairs", type=int, default=trb.PAIRS_2D, help=f"2-D pairs (default {trb.PAIRS_2D})")
    tra.add_argument("--stereo-pairs", type=int, default=trb.PAIRS_STEREO,
                     help=f"stereo pairs (default {trb.PAIRS_STEREO})")
    tra.set_defaults(reps=1, size=None)
    for p, name in ((acc, "accuracy"), (tra, "training"), (eff, "effects"), (lib, "library"), (sca, "scaling"), (qua, "quadratic"),
                    (pee, "peer"), (thr, "throughput"), (jb, "jacobian")):
        p.add_argument("--out", default=None, help=f"directory of {name}.json / {name}.md (default {RESULTS} for a "
                       f"full-size run, {SCRATCH} otherwise)")
    args = parser.parse_args(argv)
    if args.command == "peer" and args.reps is None:
        args.reps = 3 if args.quick else peer.REPS
    if args.reps < 1 or (args.size and min(args.size) < 2):
        parser.error("--reps must be ≥ 1 and --size at least 2 2")
    quick = getattr(args, "quick", False)
    size = tuple(args.size) if args.size else (accuracy.QUICK_SIZE if quick else accuracy.FULL_SIZE)
    try:
        out = results_dir(args.out, size == accuracy.FULL_SIZE and not quick, args.command)
        if args.command == "library":
            from glsim.bench import library as lb
            if args.images < 1 or args.reps < 1 or (args.max_workers is not None and args.max_workers < 1):
                parser.error("--images, --reps and --max-workers must be ≥ 1")
            size = tuple(args.size) if args.size else lb.FULL_SIZE
            full = size == lb.FULL_SIZE and args.images >= lb.FULL_IMAGES
            out = results_dir(args.out, full, "library")
            print(lb.write(lb.bench(size, args.images, args.max_workers, args.reps), out))
            return 0
        if args.command == "training":
            if args.pairs < 1 or args.stereo_pairs < 1:
                parser.error("--pairs and --stereo-pairs must be ≥ 1")
            full = args.pairs >= trb.PAIRS_2D and args.stereo_pairs >= trb.PAIRS_STEREO
            out = results_dir(args.out, full, "training")
            print(trb.write(trb.bench(args.pairs, args.stereo_pairs,
                                      log=lambda m: print(m, file=sys.stderr, flush=True)), out))
            return 0
        if args.command == "preview":
            size = tuple(args.size) if args.size else pb.FULL_SIZE
            full = (size == pb.FULL_SIZE and args.reps >= 30 and tuple(args.frame) == pb.FRAME
                    and args.drag_width == pb.DRAG_WIDTH)
            out = results_dir(args.out, full, "preview")
            report = pb.preview(size, args.reps, tuple(args.frame), args.drag_width)
            out.mkdir(parents=True, exist_ok=True)
            io.write_text(out / "preview.json", json.dumps(report, indent=2) + "\n")
            io.write_text(out / "preview.md", text := pb.markdown(report))
            print(text)
            return 0
        if args.command == "quadratic":
            size = tuple(args.size) if args.size else quadratic.FULL_SIZE
            out = results_dir(args.out, size == quadratic.FULL_SIZE, "quadratic")
            print(quadratic.write(quadratic.quadratic(size), out))
            return 0
        if args.command == "peer":
            size = tuple(args.size) if args.size else peer.QUICK_SIZE if quick else peer.FULL_SIZE
            out = results_dir(args.out, size == peer.FULL_SIZE and args.reps >= peer.REPS, "peer")
            print(peer.write(peer.peer(size, args.reps, log=lambda m: print(m, file=sys.stderr, flush=True)), out))
            return 0
        if args.command == "jacobian":
            size = tuple(args.size) if args.size else jbm.QUICK_SIZE if quick else jbm.FULL_SIZE
            out = results_dir(args.out, size == jbm.FULL_SIZE and not quick, "jacobian")
            print(jbm.write(jbm.bench(size, args.reps, log=lambda m: print(m, file=sys.stderr, flush=True)), out))
            return 0
        if args.command == "throughput":
            if args.pairs < 1:
                parser.error("--pairs must be ≥ 1")
            size = tuple(args.size) if args.size else tp.QUICK_SIZE if quick else tp.FULL_SIZE
            spps, reps, pairs, n = ((tp.QUICK_SPPS, 1, 1, tp.QUICK_ELEMENTS) if quick
                                    else (tp.SPPS, args.reps, args.pairs, tp.ELEMENTS))
            full = size == tp.FULL_SIZE and not quick and reps >= tp.REPS and pairs >= tp.PAIRS
            out = results_dir(args.out, full, "throughput")
            print(tp.write(tp.throughput(size, reps, pairs, spps, n, log=lambda m: print(m, file=sys.stderr, flush=True)),
                           out))
            return 0
        if args.command == "effects" and args.only:
            old = out / "effects.json"
            previous = json.loads(old.read_text()) if old.is_file() else None
            print(effects.write(effects.rows_only(args.only, size, previous), out))
            return 0
        if args.command == "effects":
            print(effects.write(effects.effects(size, args.reps), out))
            return 0
        if args.command == "scaling":
            try:
                sizes = [] if args.sizes == ["0"] else [tuple(int(v) for v in s.lower().split("x")) for s in
                                                        (args.sizes or [f"{w}x{h}" for w, h in scaling.FULL_SIZES])]
            except ValueError:
                parser.error("--sizes takes WxH, e.g. 1624x1234")
            if any(len(s) != 2 or min(s) < 2 for s in sizes) or min(args.elements or [1]) < 1:
                parser.error("--sizes takes WxH of at least 2x2 and --elements counts ≥ 1")
            elements = tuple(args.elements or scaling.FULL_ELEMENTS)
            full = (elements == scaling.FULL_ELEMENTS and tuple(sizes) == scaling.FULL_SIZES and not args.no_oracle
                    and args.size_elements == scaling.SIZE_ELEMENTS and args.reps >= scaling.REPS)
            out = results_dir(args.out, full, "scaling")
            report = scaling.scaling(elements, sizes, args.size_elements, args.reps, not args.no_oracle)
            print(scaling.write(report, out))
            return 0
        report = accuracy.accuracy(size, args.reps, quick)
    except GlsimError as exc:
        print(f"glsim bench: error: {exc}", file=sys.stderr)
        return 2 if not isinstance(exc, GLUnavailableError) else 1
    report["targets"] = accuracy.targets(report)
    text = accuracy.markdown(report)
    out.mkdir(parents=True, exist_ok=True)
    io.write_text(out / "accuracy.json", json.dumps(report, indent=2) + "\n")
    io.write_text(out / "accuracy.md", text)
    print(text)
    return 0
