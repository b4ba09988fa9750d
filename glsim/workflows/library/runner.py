"""Run a library plan: write its folders, render what is missing (in this process, a local
process pool or on a Dask cluster), keep the manifest current and resume (which files are good,
and ``verify``: :mod:`.audit`).

The directory rules:

* Nothing is written before the whole spec is expanded and checked (:mod:`.spec`).
* A directory holding a library of the same plan (same fingerprint in ``library.json``) is
  resumed: the good files (:mod:`.audit`) are kept, everything else is rendered (again). Any
  other non-empty directory is refused, unless ``force`` and it holds a library: then that
  library's files are removed first.
* Truth is content-addressed: every image whose truth key (:func:`.keys.truth_keys`) is the same
  points to one file ``truth/{key}.truth``, rendered and written once, by the first image of
  the key still to render (the others render their image only). A manifest row is written once
  its image and its truth file both are.
* Images and their truth are renamed into place as one group (:mod:`.worker`); the manifest
  is rewritten atomically every ``flush_s`` seconds and at the end, so it always loads. An image
  written after the last manifest flush of an interrupted run has no row, and is rendered again
  (deterministically: the same bytes) when the run is resumed.
* Temporaries of interrupted writes (``.NAME.*.part*``) are removed when a run starts and ends.
* One run writes a directory at a time, and only inside it (:mod:`glsim.io.outdir`).
"""
from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from glsim.io.hashes import sha256_bytes
from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io import outdir
from glsim.io import geometryfile
from glsim.workflows.library import manifest as mf
from glsim.workflows.library.audit import TRUTH_BAD, LibraryError, check_records, first_difference
from glsim.workflows.library.keys import TRUTH_DIR, mesh_key
from glsim.workflows.library.spec import LibraryPlan
from glsim.workflows.library.worker import WriteError, make_task, render_task

CHUNK = 8          # images per task at most (a variant with more is split)
WRITE_TEST = ".glsim-write-test"


@dataclass
class Summary:
    """What a run did."""
    out: str
    total: int = 0
    written: int = 0
    kept: int = 0
    failed: list = field(default_factory=list)      # (variant, message)
    seconds: float = 0.0
    bytes: int = 0
    render_s: float = 0.0
    truth_s: float = 0.0
    encode_s: float = 0.0
    write_s: float = 0.0
    workers: int = 1
    engine: str = "local"
    pool_restarts: int = 0

    def text(self) -> str:
        n = max(self.written, 1)
        rate = self.written / self.seconds if self.seconds > 0 else 0.0
        lines = [f"glsim library: {self.written} images written, {self.kept} kept, {len(self.failed)} failed "
                 f"of {self.total}, in {self.seconds:.1f} s ({rate:.2f} images/s, "
                 f"{self.bytes / 1e6 / max(self.seconds, 1e-9):.1f} MB/s; {self.engine}, {self.workers} worker"
                 f"{'s' if self.workers != 1 else ''}) → {self.out}/"]
        if self.written:
            lines.append(f"time per image, summed over workers: render {self.render_s / n:.3f} s, truth "
                         f"{self.truth_s / n:.3f} s, encode {self.encode_s / n:.3f} s, write {self.write_s / n:.3f} s")
        if self.pool_restarts:
            lines.append(f"a worker process died {self.pool_restarts}× and its tasks were run again")
        for vid, msg in self.failed[:5]:
            lines.append(f"failed: {vid}: {msg}")
        if self.failed:
            lines.append("run the same command again to retry the failed images (the others are kept)")
        return "\n".join(lines)


# ---- the directory ----------------------------------------------------------------------------------

def _prepare_directory(out: Path, plan: LibraryPlan, fingerprint: str, force: bool) -> bool:
    """True to resume; False for a new library. Raises LibraryError for a directory that holds
    something else. What a run killed before writing library.json leaves (its write test,
    temporaries) does not count."""
    left = lambda p: p.name == WRITE_TEST or (p.name.startswith(".") and ".part" in p.name)  # noqa: E731
    if all(left(p) for p in outdir.entries(out)):
        return False
    info = mf.read_library_info(out)
    if info is not None and info.get("fingerprint") == fingerprint and not force:
        return True
    if info is None:
        names = sorted(p.name for p in outdir.entries(out))
        shown = ", ".join(names[:3]) + (", …" if len(names) > 3 else "")
        raise LibraryError(f"{out}: is not empty ({len(names)} entries: {shown}) and holds no library — "
                           "write the library to a new or empty directory (-o)")
    if not force:
        raise LibraryError(f"{out}: holds a library of another spec ({first_difference(info, plan)}) — write to "
                           "a new directory (-o), or pass --force to replace it (its variant folders, geometry, "
                           "manifest and library.json are removed first)")
    for v in info.get("variants", []):
        vid = str(v.get("id", ""))
        if vid.startswith("v") and vid[1:].isdigit() and (out / vid).is_dir():
            shutil.rmtree(out / vid)
    for name in (mf.GEOMETRY_DIR, TRUTH_DIR):
        if (out / name).is_dir():
            shutil.rmtree(out / name)
    for name in (mf.MANIFEST, mf.LIBRARY):
        if (out / name).is_file():
            os.unlink(out / name)
    return False


def _check_writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
        with io.atomic_path(out / WRITE_TEST) as tmp:
            tmp.write_bytes(b"ok")
        os.unlink(out / WRITE_TEST)
    except OSError as exc:
        raise WriteError(f"{out}: cannot be written ({exc.strerror or exc}) — give a writable directory (-o)"
                         + (" with free space" if exc.errno == 28 else "")) from None


def _write_if_changed(path: Path, data: bytes) -> None:
    try:
        if path.read_bytes() == data:
            return
    except OSError:
        pass
    with io.atomic_path(path) as tmp:
        tmp.write_bytes(data)


def _write_setup(out: Path, plan: LibraryPlan, fingerprint: str) -> dict:
    """library.json, each variant's scene.json and the geometry files; returns
    mesh key → (geometry path relative to out, its SHA-256)."""
    mf.write_library_info(out, mf.library_info(plan, fingerprint))
    if plan.truth:
        (out / TRUTH_DIR).mkdir(exist_ok=True)
    geometry = {}
    for v in plan.variants:
        key = mesh_key(v.scene)
        if key not in geometry and not plan.truth:
            geometry[key] = ("", "")           # only truth files refer to geometry
        elif key not in geometry:
            mesh = plan.meshes[key]
            steps = sorted({j.step for j in plan.jobs if j.variant == v.id} | set(plan.steps))
            steps = [s for s in steps if s < mesh.n_steps]
            arrays = geometryfile.geometry_arrays(mesh.nodes, mesh.quads, {s: mesh.displacements[s] for s in steps},
                                                  mesh.element_labels, mesh.patches)
            data = geometryfile.geometry_bytes(arrays)
            sha = sha256_bytes(data)
            rel = f"{mf.GEOMETRY_DIR}/{sha[:16]}.npz"
            _write_if_changed(out / rel, data)
            geometry[key] = (rel, sha)
        _write_if_changed(out / v.id / "scene.json", v.scene.to_json().encode())
    return geometry


def sweep_temporaries(out: Path) -> int:
    """Remove temporaries that interrupted writes left (``.NAME.XXXX.part…``)."""
    n = 0
    for p in out.rglob(".*.part*"):
        if p.is_file() and ".part" in p.name:
            try:
                os.unlink(p)
                n += 1
            except OSError:
                pass
    return n


def _rows(records: dict, truths: dict) -> dict:
    """The records whose image and truth file are both written (the manifest's rows), with
    their truth file's size and SHA-256."""
    rows = {}
    for k, rec in records.items():
        t = rec["truth_file"]
        if not t:
            rows[k] = rec
        elif t in truths:
            rows[k] = {**rec, "truth_bytes": truths[t][0], "truth_sha256": truths[t][1]}
    return rows


# ---- running -----------------------------------------------------------------------------------------

def _tasks(out: Path, plan: LibraryPlan, todo, geometry: dict, truths: dict) -> list[dict]:
    """Tasks of ≤ CHUNK images of one variant; of each truth file not in ``truths`` (the good
    ones), the first image still to render renders it."""
    by_variant: dict[str, list] = {}
    owners, seen = set(), set(truths)
    for job in todo:
        by_variant.setdefault(job.variant, []).append(job)
        if job.truth and job.truth not in seen:
            seen.add(job.truth)
            owners.add(job)
    tasks = []
    for vid, jobs in by_variant.items():
        v = plan.variant(vid)
        rel, sha = geometry[mesh_key(v.scene)]
        for k in range(0, len(jobs), CHUNK):
            tasks.append(make_task(v, jobs[k:k + CHUNK], out, rel, sha, plan.truth_dtype, owners))
    return tasks


class _Progress:
    def __init__(self, total: int, enabled: bool):
        self.total, self.enabled = total, enabled
        self.t0 = time.perf_counter()
        self.done = 0
        self.bytes = 0

    def update(self, records) -> None:
        self.done += len(records)
        self.bytes += sum(r["bytes"] + r["truth_bytes"] for r in records)
        if not self.enabled:
            return
        dt = max(time.perf_counter() - self.t0, 1e-9)
        rate = self.done / dt
        eta = (self.total - self.done) / rate if rate > 0 else math.inf
        eta_s = f"{int(eta // 60)}m{int(eta % 60):02d}s" if math.isfinite(eta) else "?"
        sys.stderr.write(f"\rglsim library: {self.done}/{self.total} images  {rate:.2f} images/s  "
                         f"{self.bytes / 1e6 / dt:.1f} MB/s  ETA {eta_s}   ")
        if self.done >= self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    def end(self) -> None:
        if self.enabled and self.done < self.total:
            sys.stderr.write("\n")
            sys.stderr.flush()


def default_workers() -> int:
    """One per GPU where EGL lists GPUs (they would share one GPU otherwise), else one per core."""
    from glsim.workflows.library.worker import gpus
    return len(gpus()) or os.cpu_count() or 1


def _run_inprocess(tasks, on_done, fn=render_task):
    from glsim.workflows.library import worker
    try:
        for t in tasks:
            on_done(t, worker_result(t, fn))
    finally:
        worker.release()


def worker_result(task, fn=render_task):
    """Run ``fn(task)`` (default: a library task, :func:`.worker.render_task`) and return
    ("ok", records) or ("error", message); WriteError propagates."""
    try:
        return "ok", fn(task)
    except WriteError:
        raise
    except GlsimError as exc:
        return "error", str(exc)
    except (RuntimeError, ValueError, ArithmeticError) as exc:
        return "error", f"{type(exc).__name__}: {exc}"


def _kill_workers(ex) -> None:
    """Kill the pool's worker processes and wait for them to end (their writer processes end
    with them, :mod:`.lifeline`). A broken pool needs it: CPython 3.11 terminates the workers
    it knows when one dies, but a worker spawned meanwhile (by a submit racing the breakage) is
    never told to stop, and the pool's thread then joins it forever — the command hung at
    exit."""
    procs = list((getattr(ex, "_processes", None) or {}).values())
    for p in procs:
        p.kill()
    for p in procs:
        p.join(5)


def _run_pool(tasks, workers: int, on_done, summary: Summary, fn=render_task):
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    from glsim.workflows.library.worker import gpus, pool_init

    ctx = mp.get_context("spawn")
    init = (tuple(gpus()), os.getpid())    # worker k on GPU k (mod the GPU count), if any; ends with this process
    pending = list(tasks)
    while pending:
        ex = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=pool_init, initargs=init)
        futures, broken = {}, False
        try:
            try:
                for t in pending:
                    futures[ex.submit(worker_result, t, fn)] = t
            except BrokenProcessPool:  # a worker died while the tasks were being handed out
                broken = True
            except Exception as exc:
                # The same death, landing inside submit (CPython 3.11): submit passed its broken check,
                # then the pool's thread marked the pool broken and shut it, closing the queue a new
                # worker is spawned with: OSError("handle is closed"), ValueError("bad value(s) in
                # fds_to_keep") from the spawn, or RuntimeError (shut down). Only a pool marked broken
                # is taken for a death; an OSError of a sound one is named, anything else is a bug.
                if not getattr(ex, "_broken", False):
                    if isinstance(exc, OSError):
                        raise LibraryError(f"could not start a worker process ({exc}) — run the same command "
                                           "again with fewer --workers to resume") from exc
                    raise
                broken = True
            while futures:
                done, _ = wait(list(futures), return_when=FIRST_COMPLETED)
                for f in done:
                    t = futures.pop(f)
                    try:
                        result = f.result()
                    except BrokenProcessPool:
                        broken = True
                        continue
                    pending.remove(t)
                    on_done(t, result)
                if broken:
                    break
        except BaseException:
            _kill_workers(ex)
            ex.shutdown(wait=False, cancel_futures=True)
            raise
        if broken:
            _kill_workers(ex)
        ex.shutdown(wait=not broken, cancel_futures=True)
        if broken:
            summary.pool_restarts += 1
            if summary.pool_restarts > 3:
                raise LibraryError(f"worker processes died {summary.pool_restarts} times (killed, or out of memory); "
                                   f"{len(pending)} tasks were not rendered — run the same command again to resume, "
                                   "with fewer --workers if memory is short")


CONNECT_S = 15        # seconds for a Dask scheduler to answer
JOIN_S = 60           # seconds for its first worker to join


def connect(scheduler: str):
    """A Dask client of the scheduler at ``scheduler`` once a worker has joined; LibraryError
    naming the address and the fix when none answers within CONNECT_S s or no worker joins
    within JOIN_S s."""
    try:
        from distributed import Client
    except ImportError:
        raise LibraryError("--scheduler needs Dask distributed — install it with pip install 'glsim[dask]' "
                           "(or pip install distributed)") from None
    try:
        client = Client(scheduler, timeout=f"{CONNECT_S}s")
    except Exception as exc:   # OSError, TimeoutError, ValueError for a malformed address
        raise LibraryError(f"--scheduler {scheduler}: no Dask scheduler answered ({type(exc).__name__}: {exc}) — "
                           "start one with `dask scheduler` and workers with `dask worker ADDRESS --nthreads 1`, and "
                           "give its tcp://HOST:PORT") from None
    try:
        client.wait_for_workers(1, timeout=JOIN_S)
    except Exception:
        client.close()
        raise LibraryError(f"--scheduler {scheduler}: no Dask worker joined within {JOIN_S} s — start workers with "
                           f"`dask worker {scheduler} --nthreads 1` (glsim installed, the library directory "
                           "on a filesystem they can write)") from None
    return client


def _run_dask(tasks, client, on_done, summary: Summary, key: str, fn=render_task):
    from distributed import as_completed

    summary.workers = len(client.scheduler_info().get("workers", {}))
    futures = {}
    for i, t in enumerate(tasks):
        f = client.submit(worker_result, t, fn, key=f"glsim-library-{key[:12]}-{i:06d}", pure=False)
        futures[f] = t
    for f in as_completed(list(futures)):
        try:
            result = f.result()
        except WriteError:
            raise
        except Exception as exc:   # KilledWorker and the like: the task failed on every try
            result = ("error", f"{type(exc).__name__}: {exc}")
        on_done(futures[f], result)


def execute(tasks: list[dict], fn, on_done, summary: Summary, scheduler=None, key: str = "tasks") -> None:
    """Run ``fn(task)`` for every task — in this process (``summary.workers`` 1), a local process
    pool of ``summary.workers`` (a dead worker's tasks rerun in a fresh pool), or on a Dask
    cluster (``scheduler``: its tcp://HOST:PORT, or a client from :func:`connect`) — calling
    ``on_done(task, ("ok", records) | ("error", message))`` in this process as each finishes.
    ``fn`` must be importable by name (workers unpickle it)."""
    if not tasks:
        return
    if isinstance(scheduler, str):
        client = connect(scheduler)
        try:
            _run_dask(tasks, client, on_done, summary, key, fn)
        finally:
            client.close()
    elif scheduler is not None:
        _run_dask(tasks, scheduler, on_done, summary, key, fn)
    elif summary.workers == 1:
        _run_inprocess(tasks, on_done, fn)
    else:
        _run_pool(tasks, summary.workers, on_done, summary, fn)


def run(plan: LibraryPlan, out: str | Path, workers: int | None = None, scheduler: str | None = None,
        force: bool = False, progress: bool = False, flush_s: float = 2.0) -> Summary:
    """Render ``plan`` into ``out`` (see the module text); returns the :class:`Summary`. With a
    ``scheduler``, nothing is written before it has answered and a worker has joined."""
    from glsim.backends.gl.plan import environment_stage

    out = Path(out)
    if workers is not None and workers < 1:
        raise LibraryError(f"--workers {workers}: must be ≥ 1 — give the number of worker processes")
    outdir.inside(out, [rel for job in plan.jobs for rel in (job.image, job.truth) if rel], "output.pattern")
    environment_stage()   # (this process's: a worker elsewhere refuses its own bad value per image)
    check_references(plan)
    client = connect(scheduler) if scheduler else None
    try:
        with _interrupt_once(), outdir.locked(out):
            return _run(plan, out, workers, client, force, progress, flush_s)
    finally:
        if client is not None:
            client.close()


def check_references(plan: LibraryPlan) -> None:
    """Read every distinct reference image file of the plan's variants (``speckle.image``) as a
    render would, so that a missing, damaged or oversized one is refused before the library's
    directory is made (SceneError naming the variant and the key)."""
    from glsim.io.images import load_reference

    seen = set()
    for v in plan.variants:
        image = v.scene.speckle.image
        if not image or str(v.scene.resolve(image)) in seen:
            continue
        seen.add(str(v.scene.resolve(image)))
        try:
            load_reference(v.scene.resolve(image))
        except GlsimError as exc:
            raise LibraryError(f"variant {v.id}: {exc}") from None


@contextlib.contextmanager
def _interrupt_once():
    """SIGTERM (kill, timeout, SLURM) stops the run as Ctrl-C does, with KeyboardInterrupt —
    once: SIGTERM and SIGINT are ignored from the first of them until the run has stopped
    (`timeout` sends SIGTERM twice, to the command and to its process group, and a second
    KeyboardInterrupt inside the first one's clean-up would leave files and locks half done).
    Only in the main thread, where signal handlers live."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def stop(signum, frame):
        for s in old:
            signal.signal(s, signal.SIG_IGN)
        raise KeyboardInterrupt

    for s in old:
        signal.signal(s, stop)
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _run(plan: LibraryPlan, out: Path, workers, client, force: bool, progress: bool, flush_s: float) -> Summary:
    """:func:`run` holding the lock of ``out`` (``client``: a Dask client, or None)."""
    t0 = time.perf_counter()
    fingerprint = plan.fingerprint()
    resume = _prepare_directory(out, plan, fingerprint, force)
    rows = mf.read_manifest(out) if resume else {}       # (a damaged one is refused before anything is written)
    _check_writable(out)
    sweep_temporaries(out)
    geometry = _write_setup(out, plan, fingerprint)
    records, truths, todo = {}, {}, list(plan.jobs)
    if resume:
        records, problems, truths = check_records(out, plan, rows)
        todo = [job for job, what in problems if what != TRUTH_BAD]
        pending = {job.truth for job in todo}
        for job, what in problems:     # a good image whose truth file is bad: kept, unless it renders that file
            if what != TRUTH_BAD:
                continue
            if job.truth in pending:
                records[(job.variant, job.camera, job.step)] = rows[(job.variant, job.camera, job.step)]
            else:
                todo.append(job)
                pending.add(job.truth)
    workers = default_workers() if workers is None else workers
    summary = Summary(out=str(out), total=len(plan.jobs), kept=len(records),
                      workers=min(workers, max(1, len(todo))), engine="dask" if client else "local")
    tasks = _tasks(out, plan, todo, geometry, truths)
    bar = _progress = _Progress(len(todo), progress)
    last_flush = [time.perf_counter()]

    fresh = set()

    def on_done(task, result):
        status, payload = result
        if status == "error":
            summary.failed.append((task["variant"], payload))
            return
        for rec in payload:
            records[(rec["variant"], rec["camera"], rec["step"])] = rec
            fresh.add((rec["variant"], rec["camera"], rec["step"]))
            if rec["truth_sha256"]:
                truths[rec["truth_file"]] = (rec["truth_bytes"], rec["truth_sha256"])
            summary.written += 1
            summary.bytes += rec["bytes"] + rec["truth_bytes"]
            for c in ("render_s", "truth_s", "encode_s", "write_s"):
                setattr(summary, c, getattr(summary, c) + rec[c])
        bar.update(payload)
        if time.perf_counter() - last_flush[0] >= flush_s:
            mf.write_manifest(out, plan, _rows(records, truths))
            last_flush[0] = time.perf_counter()

    try:
        execute(tasks, render_task, on_done, summary, client, fingerprint)
    finally:
        _progress.end()
        try:
            mf.write_manifest(out, plan, _rows(records, truths))
        except OSError:
            pass
        sweep_temporaries(out)
    orphans = [k for k, rec in records.items() if rec["truth_file"] and rec["truth_file"] not in truths]
    summary.written -= len(fresh.intersection(orphans))   # their truth file failed: no manifest row, rendered next time
    summary.kept -= len(set(orphans) - fresh)
    summary.failed += [(vid, "the truth file of its images was not written (another task failed)")
                       for vid in dict.fromkeys(k[0] for k in orphans)]
    summary.seconds = time.perf_counter() - t0
    return summary

