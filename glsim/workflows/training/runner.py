"""Run a training plan: write its shards (one task per shard, through the library's
:func:`~glsim.workflows.library.runner.execute`: in this process, a local pool or on Dask),
keep the shards manifest current, resume and verify.

A training set's directory::

    training.json     the spec (base scene inlined), the [training] table, the shards and their variants,
                      the fingerprint
    samples.csv       one row per sample: variant, shard, the varied values (JSON)
    manifest.csv      one row per written shard: shard, samples, bytes, sha256
    shard-000000.tar  WebDataset shards (:mod:`.shards`)

Rules (as a library's): nothing is written before the whole spec is expanded and checked; a
directory holding the same plan (fingerprint) is resumed — a shard whose size and SHA-256 are its
manifest row's is kept, every other one rendered again (the same bytes); another training set or
library is refused unless ``force``; a non-empty directory holding neither is refused. Shards
are renamed into place whole; one run writes the directory at a time, and only inside it.
"""
from __future__ import annotations

import csv
import io as _io
import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io import outdir
from glsim.io.hashes import sha256_file
from glsim.limits import parse_nested, read_bounded
from glsim.workflows.library.audit import LibraryError
from glsim.workflows.training.spec import TrainingPlan

INFO = "training.json"
MANIFEST = "manifest.csv"
SAMPLES = "samples.csv"
FORMAT = "glsim-training"
VERSION = 1
COLUMNS = ("shard", "samples", "bytes", "sha256")


@dataclass
class Summary:
    """What a run did (``workers``, ``pool_restarts``: what :func:`execute` reads and counts)."""
    out: str
    total: int = 0
    samples: int = 0
    written: int = 0
    kept: int = 0
    failed: list = field(default_factory=list)
    seconds: float = 0.0
    bytes: int = 0
    workers: int = 1
    engine: str = "local"
    pool_restarts: int = 0

    def text(self) -> str:
        rate = self.samples / self.seconds if self.seconds > 0 else 0.0
        lines = [(f"glsim library: {self.written} shards written ({self.samples} pairs, {rate:.2f} pairs/s, "
                  f"{self.bytes / 1e6:.1f} MB), {self.kept} kept, {len(self.failed)} failed of {self.total}, in "
                  f"{self.seconds:.1f} s ({self.engine}, {self.workers} worker{'s' * (self.workers != 1)}) "
                  f"→ {self.out}/")]
        if self.pool_restarts:
            lines.append(f"a worker process died {self.pool_restarts}× and its shards were written again")
        lines += [f"failed: {s}: {m}" for s, m in self.failed[:5]]
        if self.failed:
            lines.append("run the same command again to retry the failed shards (the others are kept)")
        return "\n".join(lines)


def info(plan: TrainingPlan, spec: dict) -> dict:
    return {"format": FORMAT, "version": VERSION, "fingerprint": plan.fingerprint(), "spec": spec,
            "base_dir": plan.library.base_dir, "keys": list(plan.library.keys), "training": plan.training.as_dict(),
            "cameras": list(plan.cameras), "labels": list(plan.labels), "sample_bytes": plan.sample_bytes,
            "samples_per_shard": plan.per_shard,
            "shards": [{"name": s.name, "variants": list(s.variants)} for s in plan.shards]}


def stored_spec(plan: TrainingPlan) -> dict:
    """The spec as a training set stores it: the base scene inlined, [training] as given."""
    src = dict(plan.library.source)
    for k in ("truth", "steps", "cameras"):
        src.pop(k, None)
    return {**src, "training": {k: v for k, v in plan.training.as_dict().items() if v not in (None, [])}}


def read_info(out: Path) -> dict | None:
    try:
        data = parse_nested(json.loads, read_bounded(Path(out) / INFO).decode("utf-8"), INFO)
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    ok = (isinstance(data, dict) and data.get("format") == FORMAT and isinstance(data.get("shards"), list)
          and all(isinstance(s, dict) and _plain_name(s.get("name")) and isinstance(s.get("variants"), list)
                  for s in data["shards"]))
    return data if ok else None


def _plain_name(name) -> bool:
    """A shard name: a plain file name in the directory (nothing a damaged info could aim elsewhere)."""
    return isinstance(name, str) and name.startswith("shard-") and name.endswith(".tar") and "/" not in name \
        and name == Path(name).name


def manifest_text(plan_shards, rows: dict) -> str:
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for name in plan_shards:
        if name in rows:
            w.writerow([rows[name][c] for c in COLUMNS])
    return buf.getvalue()


def read_manifest(out: Path) -> dict:
    """shard → row (samples and bytes as int); rows that do not read are left out."""
    path = Path(out) / MANIFEST
    rows = {}
    try:
        text = read_bounded(path).decode("utf-8")
    except (OSError, UnicodeDecodeError):
        return rows
    try:
        for row in csv.DictReader(text.splitlines()):
            try:
                rows[row["shard"]] = {"shard": row["shard"], "samples": int(row["samples"]),
                                      "bytes": int(row["bytes"]), "sha256": row["sha256"]}
            except (KeyError, ValueError, TypeError):
                continue
    except csv.Error:
        return {}
    return rows


def samples_text(plan: TrainingPlan) -> str:
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    keys = plan.library.keys
    w.writerow(["variant", "shard", *keys])
    for s in plan.shards:
        for vid in s.variants:
            params = plan.library.variant(vid).params
            w.writerow([vid, s.name, *(json.dumps(params[k]) for k in keys)])
    return buf.getvalue()


def _good(out: Path, row: dict | None) -> bool:
    if row is None:
        return False
    path = out / row["shard"]
    try:
        return path.is_file() and not path.is_symlink() and path.stat().st_size == row["bytes"] \
            and sha256_file(path) == row["sha256"]
    except OSError:
        return False


# ---- the directory ---------------------------------------------------------------------------------

def _prepare(out: Path, plan: TrainingPlan, force: bool) -> bool:
    """True to resume, False for a new set; LibraryError for a directory holding something else."""
    from glsim.workflows.library import manifest as lmf
    from glsim.workflows.library.runner import WRITE_TEST

    left = lambda p: p.name == WRITE_TEST or (p.name.startswith(".") and ".part" in p.name)
    if all(left(p) for p in outdir.entries(out)):
        return False
    old = read_info(out)
    if old is not None and old.get("fingerprint") == plan.fingerprint() and not force:
        return True
    if old is None and lmf.read_library_info(out) is not None:
        raise LibraryError(f"{out}: holds an image library, not a training set — write the training set to a new "
                           "directory (-o)")
    if old is None:
        names = sorted(p.name for p in outdir.entries(out))
        raise LibraryError(f"{out}: is not empty ({len(names)} entries: {', '.join(names[:3])}"
                           f"{', …' * (len(names) > 3)}) and holds no training set — write it to a new or empty "
                           "directory (-o)")
    if not force:
        raise LibraryError(f"{out}: holds a training set of another spec — write to a new directory (-o), or pass "
                           "--force to replace it (its shards, manifest, samples.csv and training.json are removed "
                           "first)")
    for s in old["shards"]:
        if (out / s["name"]).is_file():
            os.unlink(out / s["name"])
    for name in (MANIFEST, SAMPLES, INFO):
        if (out / name).is_file():
            os.unlink(out / name)
    return False


def _write_if_changed(path: Path, text: str) -> None:
    try:
        if path.read_text(encoding="utf-8") == text:
            return
    except (OSError, UnicodeDecodeError):
        pass
    io.write_text(path, text)


def run(plan: TrainingPlan, spec: dict, out: str | Path, workers: int | None = None, scheduler=None,
        force: bool = False, progress: bool = False) -> Summary:
    """Write ``plan``'s shards into ``out`` (see the module text); ``spec``: the spec to store
    (:func:`stored_spec`). With a ``scheduler``, nothing is written before it has answered."""
    from glsim.workflows.library import runner as lr

    out = Path(out)
    if workers is not None and workers < 1:
        raise LibraryError(f"--workers {workers}: must be ≥ 1 — give the number of worker processes")
    outdir.inside(out, [s.name for s in plan.shards], "training")
    lr.check_references(plan.library)
    client = lr.connect(scheduler) if isinstance(scheduler, str) else scheduler
    try:
        with lr._interrupt_once(), outdir.locked(out):
            return _run(plan, spec, out, workers, client, force, progress)
    finally:
        if client is not None and isinstance(scheduler, str):
            client.close()


def _run(plan, spec, out: Path, workers, client, force: bool, progress: bool) -> Summary:
    from glsim.workflows.library import runner as lr
    from glsim.workflows.training.worker import make_task, shard_task

    t0 = time.perf_counter()
    resume = _prepare(out, plan, force)
    lr._check_writable(out)
    lr.sweep_temporaries(out)
    _write_if_changed(out / INFO, json.dumps(info(plan, spec), indent=1) + "\n")
    _write_if_changed(out / SAMPLES, samples_text(plan))
    names = [s.name for s in plan.shards]
    rows = {}
    if resume:
        old = read_manifest(out)
        rows = {n: old[n] for n in names if _good(out, old.get(n))}
    todo = [s for s in plan.shards if s.name not in rows]
    workers = lr.default_workers() if workers is None else workers
    summary = Summary(out=str(out), total=len(names), kept=len(rows), workers=min(workers, max(1, len(todo))),
                      engine="dask" if client is not None else "local")
    io.write_text(out / MANIFEST, manifest_text(names, rows))

    def on_done(task, result):
        status, payload = result
        if status == "error":
            summary.failed.append((task["shard"], payload))
            return
        for rec in payload:
            rows[rec["shard"]] = rec
            summary.written += 1
            summary.samples += rec["samples"]
            summary.bytes += rec["bytes"]
        io.write_text(out / MANIFEST, manifest_text(names, rows))
        if progress:
            sys.stderr.write(f"\rglsim library: {len(rows)}/{len(names)} shards  "
                             f"{summary.samples / max(time.perf_counter() - t0, 1e-9):.2f} pairs/s   ")
            sys.stderr.flush()

    try:
        lr.execute([make_task(plan, s, out) for s in todo], shard_task, on_done, summary, client,
                   plan.fingerprint())
    finally:
        if progress and todo:
            sys.stderr.write("\n")
        lr.sweep_temporaries(out)
    summary.seconds = time.perf_counter() - t0
    return summary


def verify(out: str | Path) -> tuple[int, list[str]]:
    """(good shards, problems) of the training set in ``out``: every shard its stored plan names
    against its manifest row (present, size, SHA-256, sample count)."""
    out = Path(out)
    data = read_info(out)
    if data is None:
        raise GlsimError(f"{out}: holds no training set (no {INFO}, or a damaged one) — give the directory "
                         "`glsim library SPEC -o DIR` wrote, or write the set again: glsim library SPEC -o DIR --force")
    rows = read_manifest(out)
    good, problems = 0, []
    for s in data["shards"]:
        name, row = s["name"], rows.get(s["name"])
        if row is None:
            problems.append(f"{name}: no manifest row (not written yet, or the run was interrupted)")
        elif row["samples"] != len(s["variants"]):
            problems.append(f"{name}: the manifest says {row['samples']} samples, the plan {len(s['variants'])}")
        elif not (out / name).is_file():
            problems.append(f"{name}: missing")
        elif (out / name).stat().st_size != row["bytes"]:
            problems.append(f"{name}: {(out / name).stat().st_size} bytes, the manifest says {row['bytes']}")
        elif sha256_file(out / name) != row["sha256"]:
            problems.append(f"{name}: SHA-256 differs from the manifest's (the file is damaged)")
        else:
            good += 1
    extra = sorted(set(rows) - {s["name"] for s in data["shards"]})
    problems += [f"{name}: a manifest row for a shard the plan does not hold" for name in extra]
    return good, problems
