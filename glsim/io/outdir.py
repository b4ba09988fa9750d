"""Output directories: every file glsim names stays inside one, and one run writes it at a time.

The lock is ``DIR/.glsim.lock``: an exclusive ``flock`` on the open file for the whole run (the
kernel drops it when the process dies, however it dies), the file holding the holder's pid, host,
start time and command. A second run is refused naming the holder; a lock file left by a run that
died is taken over with a warning. SIGTERM ends a run like Ctrl-C, so the lock is removed. The
lock file is never followed out of the directory: a link, directory or FIFO at its name is
refused by name (:func:`glsim.io.atomic.open_regular`). A directory that cannot be made or
written (a file on the way, a name too long, a read-only filesystem) is refused naming it.
"""
from __future__ import annotations

import contextlib
import errno
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
from glsim.io import atomic

LOCK = ".glsim.lock"


class OutputBusy(GlsimError):
    """Another run holds the output directory's lock (the message names it and the fix)."""


class WriteError(GlsimError):
    """An output file could not be written (a full disk, a read-only filesystem): the message
    names it; running the same command again resumes."""


def inside(out: str | Path, rels, key: str) -> list[Path]:
    """``out / rel`` for each of ``rels``; a SceneError naming ``key`` for the first that would
    resolve outside ``out`` (each folder resolved once), or naming the folder on its way that is a
    symbolic link leading out."""
    root, folders, paths = Path(out).resolve(), {}, []
    for rel in rels:
        path = Path(out) / rel
        if path.parent not in folders:
            folders[path.parent] = path.parent.resolve()
        where = folders[path.parent] / path.name
        if path.name == ".." or not where.is_relative_to(root) or where == root:
            link = _link_on_the_way(Path(out), rel)
            if link is not None:
                raise SceneError(str(link), f"is a symbolic link to {link.resolve()}, outside the output directory "
                                 f"{root}", "remove the link (glsim makes its own folders), or write to another "
                                 "directory (-o)")
            raise SceneError(key, f"{rel!r} resolves to {where}, not inside the output directory {root}",
                             "give names relative to the output directory, without '..' or a leading '/'")
        paths.append(path)
    return paths


def _link_on_the_way(out: Path, rel) -> Path | None:
    """The first folder of ``rel``'s own (with no '..' or root) that is a symbolic link, or None."""
    parts = Path(rel).parts[:-1]
    if Path(rel).is_absolute() or ".." in parts:
        return None
    folder = out
    for part in parts:
        folder = folder / part
        if folder.is_symlink():
            return folder
    return None


def entries(out: Path) -> list[Path]:
    """What ``out`` holds, a run's lock file aside."""
    return [p for p in out.iterdir() if p.name != LOCK]


def _holder(fd: int) -> dict:
    try:
        data = json.loads(os.pread(fd, 4096, 0) or b"{}")
    except ValueError:
        return {}
    return data if isinstance(data, dict) else {}


def _pid(holder: dict) -> int | None:
    pid = holder.get("pid")
    return pid if isinstance(pid, int) and not isinstance(pid, bool) and 0 < pid < 1 << 31 else None


def _alive(holder: dict) -> bool:
    """Whether the recorded holder may still run (another host's cannot be told: yes; a process
    glsim may not signal, EPERM, runs)."""
    if holder.get("host") != socket.gethostname():
        return bool(holder)
    pid = _pid(holder)
    if pid is None:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _describe(holder: dict) -> str:
    return (f"pid {holder.get('pid', '?')} on {holder.get('host', '?')}, started {holder.get('started', '?')}: "
            f"{holder.get('command', '?')}")


def _acquire(out: Path) -> int:
    """The locked file's descriptor, or OutputBusy. The lock file is opened without following a
    link and must be a regular file: one planted as a link (to a file elsewhere, or dangling), a
    directory or a FIFO is refused by name, and nothing outside ``out`` is opened or made."""
    path = out / LOCK
    fix = (f"remove it (rm -r {path}) if no glsim run is writing to {out}: the lock is a plain file glsim makes "
           "and removes itself")
    while True:
        fd = atomic.open_regular(path, os.O_RDWR | os.O_CREAT, fix, 0o644)
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
            if os.fstat(fd).st_ino == os.lstat(path).st_ino:
                break
        except FileNotFoundError:
            pass
        os.close(fd)                     # its holder removed the file as we opened it: again
    if holder and _alive(holder):        # the kernel's lock is free: that process is not a run writing here
        warnings.warn(f"{out}: took over a lock file naming a process that is running but does not hold the lock "
                      f"({_describe(holder)}; its process id was reused, or the file was not glsim's)", stacklevel=3)
    elif holder:
        warnings.warn(f"{out}: took over the lock of a glsim run that is no longer running ({_describe(holder)})",
                      stacklevel=3)
    me = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
          "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]])}
    os.ftruncate(fd, 0)
    os.pwrite(fd, json.dumps(me).encode(), 0)
    return fd


def problem(exc: OSError) -> str:
    """An OSError about making or writing an output directory, in words."""
    words = {errno.ENAMETOOLONG: "the name is too long for the filesystem (a name over 255 bytes, or a path over "
                                 "4096)",
             errno.EROFS: "the filesystem is read-only", errno.ENOSPC: "the disk is full",
             errno.EDQUOT: "the disk quota is used up",
             errno.EFBIG: "a file would exceed the size this process may write (ulimit -f)",
             errno.ENOTDIR: "a part of the path is a file, not a folder"}
    where = f" ({exc.filename})" if exc.filename and exc.errno in (errno.EACCES, errno.EPERM, errno.ENOTDIR) else ""
    return words.get(exc.errno, exc.strerror or str(exc)).rstrip(".") + where


def _make(out: Path) -> list[Path]:
    """Make ``out`` and the folders above it that are missing; those made, deepest first. A
    SceneError naming ``out`` if it cannot be made (a file on the way, a name too long, no
    permission, a read-only filesystem)."""
    made = []
    try:
        folder = out
        while not folder.is_dir():
            if os.path.lexists(folder):
                what = atomic.kind(os.lstat(folder).st_mode)
                raise SceneError(str(out), f"{folder} is {what}, not a directory" if folder != out else
                                 f"is {what}, not a directory", "give a directory for the output (-o)")
            made.append(folder)
            folder = folder.parent
        for folder in reversed(made):
            folder.mkdir()
    except OSError as exc:
        _remove_empty(made)
        raise SceneError(str(out), f"cannot be made: {problem(exc)}",
                         "give a directory you can write to for the output (-o)") from None
    return made


def _remove_empty(folders) -> None:
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


def _interrupt(signum, frame):
    raise KeyboardInterrupt


@contextlib.contextmanager
def locked(out: str | Path):
    """Hold ``out``'s lock for the block (see the module text). A directory this made is
    removed again if it is left empty (a run refused before writing leaves none)."""
    out = Path(out)
    made = _make(out)
    try:
        fd = _acquire(out)
    except OSError as exc:
        _remove_empty(made)
        raise SceneError(str(out), f"cannot be written: {problem(exc)}",
                         "give a directory you can write to for the output (-o)") from None
    except BaseException:
        _remove_empty(made)
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
        with contextlib.suppress(OSError):
            os.unlink(out / LOCK)
        os.close(fd)
        _remove_empty(made)              # those still empty: rmdir refuses the others
