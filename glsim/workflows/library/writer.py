"""Encoding and writing a library's files off the render thread.

moderngl holds the GIL through every GL call, so a writer *thread* beside the render loop
overlaps little of the encoding. Each render thread therefore hands its images to a writer
*process* (:class:`ProcessWriter`, made once per thread and kept across tasks): the image,
its coverage mask and its compact truth are copied into one of ``SLOTS`` shared-memory blocks
(anonymous memory files), a small message names the block, and the writer quantises, encodes
(TIFF/PNG, compact truth), hashes and writes them while the next image renders. A render waits
for a free block (back-pressure: at most ``SLOTS`` images in flight); the writer's first error
is raised in the render thread, at the next :meth:`~ProcessWriter.put` or at
:meth:`~ProcessWriter.drain`. The bytes are :func:`encode_and_write`'s, which the thread writer
(:class:`ThreadWriter`, where no writer process can be started: not Linux) runs as well. The
writer process ends with its parent (:mod:`.lifeline`); on SIGTERM a write in progress removes
its temporaries.

This module imports no GL and no renderer: the writer process starts in well under a second.
"""
from __future__ import annotations

import io as _io
import os
import queue
import signal
import sys
import threading
import time
from pathlib import Path

import numpy as np

from glsim.io.hashes import sha256_bytes
from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io import truthcodec

SLOTS = 2          # images in flight between a render thread and its writer
ALIGN = 64         # bytes: each array's offset in a shared block


class WriterDied(GlsimError):
    """The writer process ended while images were in flight (killed, or out of memory)."""


# ---- encoding and writing (the same bytes from either writer) -------------------------------------

def image_bytes(image: np.ndarray, bit_depth: int, fmt: str) -> bytes:
    """The bytes :func:`glsim.io.images.write_image` would write."""
    data = io.quantize(image, bit_depth)
    buf = _io.BytesIO()
    if fmt == "tiff":
        import tifffile
        tifffile.imwrite(buf, data, photometric="minisblack")
        return buf.getvalue()
    import imageio.v3 as iio
    return iio.imwrite("<bytes>", data, extension=".png")


def write_group(files: list[tuple[Path, bytes]]) -> None:
    """Write (path, bytes) pairs as one group: temporaries first, renamed in the order given."""
    with io.atomic_paths([p for p, _ in files]) as tmps:
        for tmp, (_, data) in zip(tmps, files):
            with open(tmp, "wb") as f:
                f.write(data)


def encode_and_write(out: str, job: dict, image: np.ndarray, mask: np.ndarray, truth, header: dict | None,
                     dtype: str, render_s: float) -> dict:
    """Encode and write one image of ``job`` (a task's job, with the camera's ``bit_depth``) and,
    if ``truth`` = (element, ξ, η) of :func:`glsim.io.truth.compact`, its truth file, as one
    group renamed truth first, image last; returns its manifest record. ``image`` (H, W) float
    grey levels in [0, 1] of full scale; ``mask`` (H, W) bool, the specimen's pixels;
    ``render_s`` the render's seconds. Times in the record are seconds."""
    t0 = time.perf_counter()
    data = image_bytes(image, job["bit_depth"], job["format"])
    rec = {"variant": job["variant"], "camera": job["camera"], "step": job["step"], "file": job["image"],
           "bytes": len(data), "sha256": sha256_bytes(data), "truth_file": job["truth"],
           "truth_bytes": 0, "truth_sha256": "", "render_s": render_s,
           "saturated": io.saturated_fraction(image, mask, job["bit_depth"]),
           "covered": float(mask.mean()) if mask.size else 0.0}
    t1 = time.perf_counter()
    files = []
    if truth is not None:
        tdata = truthcodec.encode_compact(*truth, header, dtype)
        rec["truth_bytes"], rec["truth_sha256"] = len(tdata), sha256_bytes(tdata)
        files.append((Path(out) / job["truth"], tdata))
    t2 = time.perf_counter()
    files.append((Path(out) / job["image"], data))
    write_group(files)
    rec.update(encode_s=t1 - t0, truth_s=t2 - t1 if truth is not None else 0.0, write_s=time.perf_counter() - t2)
    return rec


# ---- the writer process ---------------------------------------------------------------------------

class ProcessWriter:
    """A writer process fed through ``slots`` shared-memory blocks (see the module text).

    The process is a fresh interpreter running this module (``python -m``, not a
    multiprocessing child: nothing of the caller's ``__main__`` is imported again, so a script
    without an ``if __name__ == "__main__"`` guard works, and a daemonic process may start
    it); messages go through two pipes (:class:`multiprocessing.connection.Connection`); each
    block is an anonymous memory file (``memfd_create``, Linux), which the writer maps through
    ``/proc/PID/fd`` — no name to leak whatever ends the processes."""

    def __init__(self, slots: int = SLOTS):
        import subprocess
        from multiprocessing.connection import Connection

        if not hasattr(os, "memfd_create") or not os.path.isdir(f"/proc/{os.getpid()}/fd"):
            raise OSError("no memfd_create or /proc (Linux only)")
        down, up = os.pipe(), os.pipe()
        env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in sys.path if p))
        self.proc = subprocess.Popen([sys.executable, "-m", __name__, str(down[0]), str(up[1]), str(os.getpid())],
                                     pass_fds=(down[0], up[1]), stdin=subprocess.DEVNULL, env=env)
        os.close(down[0])
        os.close(up[1])
        self.conn = Connection(down[1], readable=False)
        self.replies = Connection(up[0], writable=False)
        self.blocks: list = [None] * slots          # (serial, fd, mmap) per slot
        self.serial = 0
        self.free = list(range(slots))
        self.records: list[dict] = []
        self.error: BaseException | None = None

    def alive(self) -> bool:
        return self.proc.poll() is None

    def put(self, out: str, job: dict, image, mask, truth, header, dtype: str, render_s: float) -> None:
        """Hand one image over (arguments as :func:`encode_and_write`); waits for a free block."""
        while not self.free:
            self._receive()
        self._raise()
        arrays = {"image": image, "mask": mask}
        if truth is not None:
            arrays.update(element=truth[0], xi=truth[1], eta=truth[2])
        layout, size = [], 0
        for name, a in arrays.items():
            layout.append((name, a.dtype.str, a.shape, size))
            size += -(-a.nbytes // ALIGN) * ALIGN
        slot = self.free.pop()
        serial, fd, block = self._block(slot, size)
        for (name, dt, shape, offset), a in zip(layout, arrays.values()):
            np.ndarray(shape, dt, buffer=block, offset=offset)[...] = a
        try:
            self.conn.send((slot, (serial, fd, len(block)), layout, (out, job, header, dtype, render_s)))
        except OSError:
            self._died()

    def _died(self):
        self.free = list(range(len(self.blocks)))
        raise WriterDied(f"the library's writer process (pid {self.proc.pid}) ended while images were being "
                         "written (killed, or out of memory) — run the same command again to resume") from None

    def _block(self, slot: int, size: int):
        import mmap

        b = self.blocks[slot]
        if b is None or len(b[2]) < size:     # free: the writer is done with it
            self._drop(slot)
            fd = os.memfd_create(f"glsim-writer-{slot}", os.MFD_CLOEXEC)
            os.ftruncate(fd, max(size, ALIGN))
            self.serial += 1
            b = self.blocks[slot] = (self.serial, fd, mmap.mmap(fd, max(size, ALIGN)))
        return b

    def _drop(self, slot: int) -> None:
        if self.blocks[slot] is not None:
            _, fd, block = self.blocks[slot]
            block.close()
            os.close(fd)
            self.blocks[slot] = None

    def _receive(self) -> None:
        try:
            status, slot, payload = self.replies.recv()
        except (EOFError, OSError):
            self._died()
        self.free.append(slot)
        if status == "ok":
            self.records.append(payload)
        elif self.error is None:
            self.error = payload

    def _raise(self) -> None:
        if self.error is not None:
            error, self.error = self.error, None
            raise error

    def drain(self) -> list[dict]:
        """Wait until every image handed over is written; their records. Raises the writer's
        first error (the images after it are written, but not in the records)."""
        while len(self.free) < len(self.blocks):
            self._receive()
        records, self.records = self.records, []
        self._raise()
        return records

    def close(self) -> None:
        try:
            self.conn.send(None)
        except OSError:
            pass
        try:
            self.proc.wait(5)
        except Exception:    # noqa: BLE001 — subprocess.TimeoutExpired
            self.proc.kill()
            self.proc.wait(5)
        for slot in range(len(self.blocks)):
            self._drop(slot)
        self.conn.close()
        self.replies.close()


_stopped: list[int] = []   # the writer process's exit status, when a SIGTERM came in a finalizer or the set-up
_exiting: list[int] = []   # the exit status, once a SIGTERM raised it
_serving: list[bool] = []  # non-empty once the set-up (the lifeline thread's start) is done


def _stop(signum, frame):
    """SIGTERM in the writer process: SystemExit, so that a write in progress removes its
    temporaries (atomic_paths). Raised once: a SIGTERM while that exit unwinds (the kernel's
    parent-death signal and the lifeline's can both come, at once where the parent died as the
    writer started) is ignored — raised in the temporaries' removal or in the interpreter's
    shutdown, it would cut the one short and print a traceback in the other. Raised inside a
    finalizer (``__del__``, such as a pipe's being collected), Python would print it as
    "Exception ignored" with a traceback and go on: there the status is kept and the loop
    raises it before its next message. Kept too during the set-up: Thread.start waits on a
    Condition, and SystemExit raised where that wait takes its lock back leaves the lock released
    twice (a RuntimeError and its traceback). Blocking the signal there would not do: Python runs
    its handler in the main thread whichever thread the kernel hands the signal to, and threads
    started at import (numpy's BLAS) do not block it."""
    if _exiting:
        return
    if not _serving or (frame is not None and frame.f_code.co_name == "__del__"):
        _stopped.append(128 + signum)
        return
    _exiting.append(128 + signum)
    raise SystemExit(128 + signum)


def serve(conn, replies, parent: int) -> None:
    """The writer process: for each message (slot, block, layout, arguments) run
    :func:`encode_and_write` on the arrays in that block and answer ("ok", slot, record) or
    ("error", slot, exception) on ``replies``; end at None, when the parent ends, or on SIGTERM."""
    import mmap

    from glsim.workflows.library.lifeline import die_with_parent

    signal.signal(signal.SIGINT, signal.SIG_IGN)       # Ctrl-C is the parent's to handle
    blocks: dict[int, tuple] = {}                      # slot → (serial, mmap)
    try:
        signal.signal(signal.SIGTERM, _stop)
        die_with_parent(parent)
        _serving.append(True)          # from here a SIGTERM raises; one before is kept in _stopped
        while not _stopped and (msg := conn.recv()) is not None:
            slot, (serial, fd, size), layout, args = msg
            if blocks.get(slot, (None,))[0] != serial:
                if slot in blocks:
                    blocks[slot][1].close()
                f = os.open(f"/proc/{parent}/fd/{fd}", os.O_RDWR)
                try:
                    blocks[slot] = (serial, mmap.mmap(f, size))
                finally:
                    os.close(f)
            a = {k: np.ndarray(shape, dt, buffer=blocks[slot][1], offset=off) for k, dt, shape, off in layout}
            out, job, header, dtype, render_s = args
            truth = (a["element"], a["xi"], a["eta"]) if "element" in a else None
            try:
                reply = ("ok", slot, encode_and_write(out, job, a["image"], a["mask"], truth, header, dtype, render_s))
            except Exception as exc:   # noqa: BLE001 — sent to the render thread, which raises it
                reply = ("error", slot, _portable(exc))
            del a, truth
            replies.send(reply)
        if _stopped:
            raise SystemExit(_stopped[0])
    except (EOFError, OSError):         # the parent died, or closed its end
        pass
    finally:   # nothing in progress now: a SIGTERM during the interpreter's shutdown ends it quietly
        signal.signal(signal.SIGTERM, lambda signum, frame: os._exit(128 + signum))


def main(argv=None) -> None:
    """``python -m glsim.workflows.library.writer READ_FD WRITE_FD PARENT_PID`` (ProcessWriter starts it)."""
    from multiprocessing.connection import Connection

    rfd, wfd, parent = (int(a) for a in (sys.argv[1:] if argv is None else argv))
    serve(Connection(rfd, writable=False), Connection(wfd, readable=False), parent)


def _portable(exc: Exception) -> Exception:
    """``exc`` if it survives pickling (OSError keeps errno, strerror and filename), else a
    RuntimeError with its text."""
    import pickle
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:   # noqa: BLE001
        return RuntimeError(f"{type(exc).__name__}: {exc}")


# ---- the fallback: a thread -------------------------------------------------------------------------

class ThreadWriter:
    """:class:`ProcessWriter`'s interface on a background thread of this process (it shares
    the GIL with the render loop)."""

    def __init__(self, slots: int = SLOTS):
        self.q: queue.Queue = queue.Queue(slots)
        self.records: list[dict] = []
        self.error: BaseException | None = None
        self.pending = 0
        self.done = threading.Condition()
        self.thread = threading.Thread(target=self._run, name="glsim-library-writer", daemon=True)
        self.thread.start()

    def alive(self) -> bool:
        return self.thread.is_alive()

    def _run(self) -> None:
        while (item := self.q.get()) is not None:
            try:
                rec, err = encode_and_write(*item), None
            except BaseException as exc:   # noqa: BLE001 — raised in the render thread
                rec, err = None, exc
            with self.done:
                if rec is not None:
                    self.records.append(rec)
                elif self.error is None:
                    self.error = err
                self.pending -= 1
                self.done.notify_all()

    def put(self, *item) -> None:
        with self.done:
            if self.error is not None:
                error, self.error = self.error, None
                raise error
            self.pending += 1
        self.q.put(item)

    def drain(self) -> list[dict]:
        with self.done:
            self.done.wait_for(lambda: self.pending == 0)
            records, self.records = self.records, []
            if self.error is not None:
                error, self.error = self.error, None
                raise error
        return records

    def close(self) -> None:
        self.q.put(None)
        self.thread.join()


KIND = "process"     # "thread": every writer is a ThreadWriter


def make_writer():
    """A ProcessWriter, or a ThreadWriter where none can be started (not Linux) or KIND says so."""
    if KIND == "process":
        try:
            return ProcessWriter()
        except OSError as exc:
            print(f"glsim library: no writer process ({exc}); encoding on a thread instead", file=sys.stderr)
    return ThreadWriter()


if __name__ == "__main__":
    main()
