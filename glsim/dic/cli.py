"""``glsim verify {run,compare,sweep,sweep-compare,frontier,backends}``: glsim's images measured by
an independent DIC (pyvale, run by the interpreter of ``.venv-verify``: ``make verify``,
``make sweep``), compared with the imposed coordinates; results in ``bench/results``."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from glsim.errors import GlsimError
from glsim.io import images as io


# ---- glsim verify sweep / sweep-compare / frontier / backends ----------------------------------
def add_sweep_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``glsim verify sweep``."""
    from glsim.dic.sweep import DIC_PYTHON, DIC_SCRIPT, SIZE
    p.add_argument("--exchange", default="build/sweep", help="exchange folder (default build/sweep)")
    p.add_argument("--size", type=int, nargs=2, default=SIZE, metavar=("W", "H"),
                   help="image size in px (the plate scales with it; default 512 512)")
    p.add_argument("--backend", choices=("gl", "cpu"), default="gl")
    p.add_argument("--python", default=str(DIC_PYTHON), help="interpreter with pyvale")
    p.add_argument("--script", default=str(DIC_SCRIPT))
    add_results_arguments(p)


def add_results_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--results", default="bench/results", help="where sweep.* and frontier.png go")
    p.add_argument("--accuracy", default=None, help="accuracy.json (default RESULTS/accuracy.json)")


def add_backends_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("gl_json", help="sweep.json of a --backend gl sweep")
    p.add_argument("cpu_json", help="sweep.json of a --backend cpu sweep")
    p.add_argument("--results", default="bench/results", help="where sweep_backends.json/.md go")


def sweep_command(args: argparse.Namespace) -> int:
    """Run a parsed ``sweep``, ``sweep-compare``, ``frontier`` or ``backends`` command."""
    from glsim.dic.sweep import MIN_SIZE, run_dic, write_exchange
    from glsim.bench.formatting import num
    from glsim.dic.sweep_report import backend_agreement, backend_markdown, report

    if args.command == "backends":
        agreement = backend_agreement(*(json.loads(Path(p).read_text()) for p in (args.gl_json, args.cpu_json)))
        out = Path(args.results)
        io.write_text(out / "sweep_backends.json", json.dumps(agreement, indent=2) + "\n")
        io.write_text(out / "sweep_backends.md", text := backend_markdown(agreement))
        print(text)
        return 0
    try:
        if args.command == "sweep":
            if min(args.size) < MIN_SIZE:
                raise GlsimError(f"--size {args.size[0]} {args.size[1]}: at least {MIN_SIZE} px per side is needed "
                                 f"(smaller plates leave pyvale's DIC too few subsets); give e.g. --size 512 512")
            t0 = time.perf_counter()
            path = write_exchange(args.exchange, tuple(args.size), backend=args.backend)
            print(f"glsim sweep: exchange folder {path.parent}/ written ({time.perf_counter() - t0:.1f} s)", flush=True)
            seconds = run_dic(args.exchange, args.python, args.script)
            print(f"glsim sweep: DIC {seconds:.1f} s", flush=True)
        exchange = args.exchange if args.command in ("sweep", "sweep-compare") else None
        if exchange is None and not Path(args.accuracy or Path(args.results) / "accuracy.json").is_file():
            raise GlsimError(f"{args.accuracy or Path(args.results) / 'accuracy.json'} not found: "
                             "run `glsim bench accuracy` first, or give --accuracy")
        sweep = report(exchange, args.results, args.accuracy)
    except GlsimError as exc:
        print(f"glsim sweep: error: {exc}", file=sys.stderr)
        return 2
    if sweep is not None:
        for r in sweep["results"]:
            print(f"{r['sequence']:18s} {r['run']}: max |bias u| {r['max_abs_bias_u']:.2e} px, max std "
                  f"{r['max_std_u']:.2e} px, max |u − u_model| {num(r['max_abs_gen_u'], '.1e')} px")
    print(f"glsim sweep: wrote {args.results}/" + ("sweep.json, sweep.png, " if exchange else "")
          + "sweep.md, frontier.png")
    return 0


# ---- glsim verify -------------------------------------------------------------------------------
def parser() -> argparse.ArgumentParser:
    from glsim.dic.verify import DIC_PYTHON, DIC_SCRIPT, FULL_SIZE, MESH_DIVISIONS, SPECKLE_SIGMA_PX

    ap = argparse.ArgumentParser(prog="glsim verify", description="the independent stereo-DIC check "
                                 "(pyvale in .venv-verify), the rigid-body sweep and the frontier")
    sub = ap.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="render, run the DIC (verify/dic.py in .venv-verify), compare")
    run.add_argument("--size", type=int, nargs=2, default=FULL_SIZE, metavar=("W", "H"),
                     help="image size in px (the rig scales with it; default 1624 1234)")
    run.add_argument("--exchange", default="build/verify", help="exchange folder (default build/verify)")
    run.add_argument("--mesh-divisions", type=int, default=MESH_DIVISIONS)
    run.add_argument("--sigma", type=float, default=SPECKLE_SIGMA_PX,
                     help="speckle Gaussian low-pass, camera-0 px (0: none)")
    run.add_argument("--backend", choices=("gl", "cpu"), default="gl")
    run.add_argument("--python", default=str(DIC_PYTHON), help="interpreter with pyvale")
    run.add_argument("--script", default=str(DIC_SCRIPT))
    cmp_ = sub.add_parser("compare", help="compare an exchange folder's DIC results again")
    cmp_.add_argument("exchange")
    for p in (run, cmp_):
        p.add_argument("--results", default="bench/results", help="where verify.json/.md go")
    add_sweep_arguments(sub.add_parser("sweep", help="rigid-body sweep: render, verify/dic2d.py "
                                       "(pyvale 2-D DIC), S-curves → bench/results/sweep.*"))
    again = sub.add_parser("sweep-compare", help="report a sweep exchange folder's DIC results again")
    again.add_argument("exchange")
    add_results_arguments(again)
    add_results_arguments(sub.add_parser("frontier", help="frontier.png and sweep.md from "
                                         "accuracy.json (and sweep.json)"))
    add_backends_arguments(sub.add_parser("backends", help="GL against the CPU oracle through "
                                          "the DIC, from a gl and a cpu sweep.json"))
    return ap


def _print_summary(res: dict) -> None:
    for run in res["runs"]:
        for s in run["states"]:
            cells = ", ".join(f"{r['dir']} {r['mean_px']:+.1e}±{r['std_px']:.1e}" for r in s["rows"])
            print(f"{run['name']:12s} {s['label']:10s} px: {cells}")


def main(argv: list[str] | None = None) -> int:
    """``glsim verify …``; returns the exit status."""
    from glsim.dic.verify import report, run_dic, write_exchange

    args = parser().parse_args(argv)
    if args.command in ("sweep", "sweep-compare", "frontier", "backends"):
        return sweep_command(args)
    try:
        if args.command == "run":
            path = write_exchange(args.exchange, args.size, args.mesh_divisions, args.sigma, backend=args.backend)
            print(f"glsim verify: exchange folder {path.parent}/ written")
            run_dic(args.exchange, args.python, args.script)
        res = report(args.exchange, args.results)
    except GlsimError as exc:
        print(f"glsim verify: error: {exc}", file=sys.stderr)
        return 2
    _print_summary(res)
    print(f"glsim verify: wrote {Path(args.results) / 'verify.json'} and verify.md")
    return 0
