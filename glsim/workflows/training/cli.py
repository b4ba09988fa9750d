"""``glsim library``'s training mode: a spec with ``[training]``, or a training set's directory
(resume, ``--verify``). The library command hands over when :func:`handles` says so."""
from __future__ import annotations

import sys
from pathlib import Path

from glsim.errors import GlsimError, interrupted


def handles(src: Path) -> bool:
    """Whether ``src`` is a training set's directory or a spec with a [training] table (a spec
    that does not read is the library's to refuse)."""
    from glsim.workflows.library.spec import SpecError, read_spec
    from glsim.workflows.training.runner import INFO
    from glsim.workflows.training.spec import is_training

    if src.is_dir():
        return (src / INFO).is_file()
    try:
        return is_training(read_spec(src)[0])
    except (SpecError, OSError):
        return False


def main(args) -> int:
    """The library command's parsed ``args`` for a training spec or set."""
    from glsim.workflows.training import runner
    from glsim.workflows.training.spec import expand_training, load_training

    src = Path(args.source)
    try:
        if src.is_dir():
            if args.dry_run or args.output:
                raise GlsimError(f"{src} is a training set's directory: --dry-run and -o take a spec file — give "
                                 "the SPEC.toml, or leave them out to resume this training set")
            if args.verify:
                good, problems = runner.verify(src)
                for p in problems[:20]:
                    print(f"bad: {p}")
                if len(problems) > 20:
                    print(f"… and {len(problems) - 20} more")
                print(f"glsim library --verify: {good} shards good, {len(problems)} problems in {src}/"
                      + (" — run `glsim library DIR` to write them again" if problems else ""))
                return 1 if problems else 0
            data = runner.read_info(src)
            if data is None:
                raise GlsimError(f"{src}: holds no training set (a damaged {runner.INFO}) — give the spec file")
            plan, spec, out = expand_training(data["spec"], data["base_dir"]), data["spec"], src
        else:
            if args.verify:
                raise GlsimError(f"--verify checks a training set's directory, and {src} is not one — give the DIR "
                                 "it was written to")
            plan = load_training(src, sample=40 if args.dry_run else None)
            spec = runner.stored_spec(plan)
            out = Path(args.output) if args.output else src.with_suffix("")
        if args.dry_run:
            n = plan.library.n_variants
            print(f"{n} samples ({'the first and last 40 checked; ' * plan.library.sampled}cameras "
                  f"{', '.join(plan.cameras)}; step 0 and {plan.training.step}), about {plan.sample_bytes / 1e6:.3g} "
                  f"MB each: {plan.per_shard} per shard of {plan.training.shard_bytes / 1e9:.3g} GB, "
                  f"{-(-n // plan.per_shard)} shards")
            print("dry run: nothing was written")
            return 0
        summary = runner.run(plan, spec, out, workers=args.workers, scheduler=args.scheduler, force=args.force,
                             progress=not args.quiet)
    except GlsimError as exc:
        print(f"glsim library: error: {exc}", file=sys.stderr)
        return 2
    except BaseException as exc:
        if not interrupted(exc):
            raise
        print("glsim library: interrupted — no partial shard was left; run the same command again to resume",
              file=sys.stderr)
        return 130
    print(summary.text())
    return 1 if summary.failed else 0
