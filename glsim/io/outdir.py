"""Output directories: every file glsim names stays inside one, and one run writes it at a time.

The lock is ``DIR/.glsim.lock``: an exclusive ``flock`` on the open file for the whole run (the
kernel drops it when the process dies, however it dies), the file holding the holder's pid, host,
start time and command. A second run is refused naming the holder; a lock file left by a run that
died is taken over with a warning. SIGTERM ends a run like Ctrl-C, so the lock is removed.
"""
from __future__ import annotations

import contextlib
import fcntl
import json
import os
import signal
import socket
import sys
import threading
import time
import warnings
from pathlib import Path

from glsim.errors import GlsimError, SceneError

LOCK = ".glsim.lock"


class OutputBusy(GlsimError):
    """Another run holds the output directory's lock (the message names it and the fix)."""


def inside(out: str | Path, rels, key: str) -> list[Path]:
    """``out / rel`` for each of ``rels``; a SceneError naming ``key`` for the first that would
    resolve outside ``out`` (each folder resolved once)."""
    root, folders, paths = Path(out).resolve(), {}, []
    for rel in rels:
        path = Path(out) / rel
        if path.parent not in folders:
            folders[path.parent] = path.parent.resolve()
        where = folders[path.parent] / path.name
        if path.name == ".." or not where.is_relative_to(root) or where == root:
            raise SceneError(key, f"{rel!r} resolves to {where}, not inside the output directory {root}",
                             "give names relative to the output directory, without '..' or a leading '/'")
        paths.append(path)
    return paths


def entries(out: Path) -> list[Path]:
    """What ``out`` holds, a run's lock file aside."""
    return [p for p in out.iterdir() if p.name != LOCK]


def _holder(fd: int) -> dict:
    try:
        data = json.loads(os.pread(fd, 4096, 0) or b"{}")
    except ValueError:
        return {}
    return data if isinstance(data, dict) else {}


def _alive(holder: dict) -> bool:
    """Whether the recorded holder may still run (another host's cannot be told: yes)."""
    if holder.get("host") != socket.gethostname():
        return bool(holder)
    try:
        os.kill(int(holder.get("pid", 0)), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, ValueError, OverflowError):
        return True
    return True


def _describe(holder: dict) -> str:
    return (f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}, started {holder.get('started', '?')}: "
            f"{holder.get('command', '?')}")


def _acquire(out: Path) -> int:
    """The locked file's descriptor, or OutputBusy."""
    path = out / LOCK
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        holder = _holder(fd)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            busy = False
        except BlockingIOError:
            busy = True
        except OSError:                  # a filesystem without locks: the recorded holder decides
            busy = _alive(holder)
        if busy:
            os.close(fd)
            raise OutputBusy(f"{out}: another glsim run is writing here ({_describe(holder)}) — wait for it to "
                             f"end or stop it (kill {holder.get('pid', 'PID')}), or write to another directory (-o)")
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)                     # its holder removed the file as we opened it: again
    if holder:
        warnings.warn(f"{out}: took over the lock of a glsim run that is no longer running ({_describe(holder)})",
                      stacklevel=3)
    me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
          "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])}
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(me).encode(), 0)
    return fd


def _interrupt(signum, frame):
    raise KeyboardInterrupt


@contextlib.contextmanager
def locked(out: str | Path):
    """Hold ``out``'s lock for the block (see the module text). A directory this made is
    removed again if it is left empty (a run refused before writing leaves none)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise SceneError(str(out), "is a file, not a directory", "give a directory for the output (-o)")
    made = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        fd = _acquire(out)
    except BaseException:
        if made:
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    main = threading.current_thread() is threading.main_thread()
    term = signal.getsignal(signal.SIGTERM) if main else None
    if term == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, _interrupt)
    try:
        yield
    finally:
        if term == signal.SIG_DFL:
            signal.signal(signal.SIGTERM, term)
        with contextlib.suppress(FileNotFoundError):
            os.unlink(out / LOCK)
        os.close(fd)
        if made and not any(out.iterdir()):
            with contextlib.suppress(OSError):
                out.rmdir()
