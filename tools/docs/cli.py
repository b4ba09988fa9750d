"""``python -m tools.docs [--check] [--root DIR]``, run from the repository root: regenerate (or
check) the README/docs figures that come from bench/results."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from glsim.errors import GlsimError
from tools.docs import regions

PROG = "python -m tools.docs"


def main(argv: list[str] | None = None) -> int:
    """Regenerate (or, with ``--check``, compare) every generated region; returns the exit status
    (1 when --check finds a difference, 2 on an error)."""
    parser = argparse.ArgumentParser(prog=PROG, description="README and docs figures from the results files")
    parser.add_argument("--check", action="store_true", help="fail if any generated region differs; write nothing")
    parser.add_argument("--root", default=".", help="repository root (default: the working directory)")
    args = parser.parse_args(argv)
    root = Path(args.root)
    try:
        if args.check:
            diffs = regions.check(root)
            for d in diffs:
                print(d)
            if diffs:
                print(f"{PROG}: generated regions differ from bench/results; run `{PROG}` to regenerate them (edit "
                      "the text outside the regions, or its generator in tools/docs/)", file=sys.stderr)
                return 1
            print(f"{PROG}: every generated region matches its results file")
            return 0
        changed = regions.write(root)
    except GlsimError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    print(f"{PROG}: regenerated {', '.join(changed) if changed else 'nothing (all up to date)'}")
    return 0
