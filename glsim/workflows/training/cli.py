"""``glsim library``'s training mode: a spec with ``[training]``, or a training set's directory
(resume, ``--verify``). The library command hands over when :func:`handles` says so."""
from __future__ import annotations

import time
from pathlib import Path

from glsim.errors import GlsimError


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
    """The library command's parsed ``args`` for a training spec or set (its errors and an
    interrupt are reported by the library command, which calls this)."""
    from glsim.workflows.library.audit import print_verify
    from glsim.workflows.training import runner
    from glsim.workflows.training.spec import expand_training, load_training

    src = Path(args.source)
    if src.is_dir():
        if args.dry_run or args.output:
            raise GlsimError(f"{src} is a training set's directory: --dry-run and -o take a spec file — give "
                             "the SPEC.toml, or leave them out to resume this training set")
        if args.verify:
            good, problems = runner.verify(src)
            return print_verify(good, problems, "shards", src, "run `glsim library DIR` to write them again")
        data = runner.read_info(src)
        if data is None:
            raise GlsimError(f"{src}: holds no training set (a damaged {runner.INFO}) — give the spec file")
        plan, spec, out = expand_training(data["spec"], data["base_dir"]), data["spec"], src
    else:
        if args.verify:
            raise GlsimError(f"--verify checks a training set's directory, and {src} is not one — give the DIR "
                             "it was written to")
        t0 = time.perf_counter()
        plan = load_training(src, sample=40 if args.dry_run else None)
        plan_s = (time.perf_counter() - t0) / len(plan.library.variants)
        spec = runner.stored_spec(plan)
        out = Path(args.output) if args.output else src.with_suffix("")
    if args.dry_run:
        n = plan.library.n_variants
        print(f"{n} samples ({'the first and last 40 checked; ' * plan.library.sampled}cameras "
              f"{', '.join(plan.cameras)}; step 0 and {plan.training.step}), at most {_size(plan.sample_bytes)} "
              f"each: {plan.per_shard} per shard of {_size(plan.training.shard_bytes)}, "
              f"{-(-n // plan.per_shard)} shards")
        print(_estimate_line(plan, plan_s))
        print("dry run: nothing was written")
        return 0
    summary = runner.run(plan, spec, out, workers=args.workers, scheduler=args.scheduler, force=args.force,
                         progress=not args.quiet)
    print(summary.text())
    return 1 if summary.failed else 0


def measure(plan) -> float:
    """Seconds of one sample on this machine: the first variant made into a shard's members
    (rendered, labelled, encoded; nothing written) twice, the second timed (the set-up — context,
    programs, reference image — is paid once per set)."""
    import warnings

    from glsim.workflows.library import worker as lw
    from glsim.workflows.training.spec import Shard
    from glsim.workflows.training.worker import make_task, sample_members

    v = plan.library.variants[0]
    task = make_task(plan, Shard("dry-run", (v.id,)), Path("."))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sample_members(task, task["samples"][0])
            t0 = time.perf_counter()
            sample_members(task, task["samples"][0])
            return time.perf_counter() - t0
    finally:
        lw.release()


def _estimate_line(plan, plan_s: float) -> str:
    try:
        one = measure(plan)
    except (GlsimError, RuntimeError, OSError, ValueError) as exc:
        return f"estimated: not measured — the first sample did not render here ({type(exc).__name__}: {exc})"
    n = plan.library.n_variants
    return (f"estimated: about {_duration(n * (one + plan_s))} on one worker (measured here: {plan.library.variants[0].id} "
            f"in {one:.3g} s — rendered at both steps, labelled, encoded — and {1000 * plan_s:.2g} ms to expand and "
            "check it; a set pays its GL set-up once)")


def _size(n: float) -> str:
    """Bytes in words (as the library's dry run writes them)."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.3g} {unit}"
        n /= 1000


def _duration(s: float) -> str:
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.0f} min" if s < 7200 else f"{s / 3600:.1f} h"
