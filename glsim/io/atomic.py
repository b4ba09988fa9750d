"""Atomic writes: files appear under their names complete or not at all (temporary name in the
same directory, then rename), singly or as a group renamed in a chosen order.

Nothing planted in an output directory is written through: temporaries get fresh random names
(``.NAME.XXXXXXXX.partSUFFIX``) made with O_EXCL and O_NOFOLLOW, so no link or other file there
is ever opened; before a temporary is renamed it must still be the regular file made (same
inode, one link), and a rename replaces a link at the final name instead of following it. Files
glsim opens by name for writing (a lock, a log it appends to, a temporary handed to a writer
that takes a file object) go through :func:`open_regular`: O_NOFOLLOW, and a regular file with
one link, or an error naming what is there instead.
"""
from __future__ import annotations

import contextlib
import errno
import os
import re
import stat
import tempfile
from pathlib import Path

from glsim.errors import SceneError

# mkstemp's names: prefix, 8 characters of its alphabet, suffix (see atomic_paths)
_TEMPORARY = re.compile(r"\.(?P<name>.+)\.[a-z0-9_]{8}\.part(?P<suffix>.*)")


def temporary_of(name: str) -> str | None:
    """The file name that the temporary ``name`` of :func:`atomic_paths` stands for
    (``.a.tif.k2j4x9_q.part.tif`` → ``a.tif``), or None if ``name`` is not one."""
    m = _TEMPORARY.fullmatch(name)
    return m["name"] if m and m["suffix"] == Path(m["name"]).suffix else None


def kind(mode: int) -> str:
    """What a file of ``st_mode`` is, in words ("a directory", "a symbolic link", …)."""
    kinds = ((stat.S_ISREG, "a regular file"), (stat.S_ISLNK, "a symbolic link"), (stat.S_ISDIR, "a directory"),
             (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"))
    return next((k for test, k in kinds if test(mode)), "not a regular file")


def open_regular(path: str | Path, flags: int, fix: str, mode: int = 0o666, one_link: bool = True) -> int:
    """``os.open(path, flags)`` without following a symbolic link (O_NOFOLLOW, O_CLOEXEC; O_NONBLOCK
    so that a FIFO does not wait): the descriptor of a regular file with one link (any number with
    ``one_link=False``, for reading). SceneError naming ``path``, what is there instead and ``fix``
    otherwise (a link, a directory, a FIFO, a file with another name elsewhere)."""
    try:
        fd = os.open(path, flags | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK, mode)
    except OSError as exc:
        found = {errno.ELOOP: "a symbolic link", errno.EISDIR: "a directory", errno.ENXIO: "a FIFO or socket"}
        if exc.errno not in found:
            raise
        raise SceneError(str(path), f"is {found[exc.errno]}, not a file glsim wrote", fix) from None
    st = os.fstat(fd)
    if stat.S_ISREG(st.st_mode) and (st.st_nlink == 1 or not one_link):
        return fd
    os.close(fd)
    what = kind(st.st_mode) if not stat.S_ISREG(st.st_mode) else f"a file with {st.st_nlink} names (hard links)"
    raise SceneError(str(path), f"is {what}, not a file glsim wrote", fix)


def open_temporary(tmp: str | Path, mode: str = "wb"):
    """The temporary ``tmp`` of :func:`atomic_paths` opened for writing (truncated), through
    :func:`open_regular`: for writers that take a file object."""
    fd = open_regular(tmp, os.O_WRONLY | os.O_TRUNC, "run the same command again")
    return os.fdopen(fd, mode, **({} if "b" in mode else {"encoding": "utf-8"}))


def _still_made(tmp: Path, made: os.stat_result) -> None:
    """SceneError unless ``tmp`` is still the regular file made (not replaced by a link or another file)."""
    st = os.lstat(tmp)
    if (st.st_dev, st.st_ino) != (made.st_dev, made.st_ino) or not stat.S_ISREG(st.st_mode) or st.st_nlink != 1:
        raise SceneError(str(tmp), "was replaced while glsim wrote it (by another process in the output directory)",
                         "make sure that nothing else writes to the output directory, then run the same command again")


@contextlib.contextmanager
def atomic_paths(paths):
    """Yield temporary paths next to each of ``paths``; on success rename them onto ``paths``
    in the order given (put the file whose presence marks the group complete last). On any
    exception, KeyboardInterrupt included, every temporary file is removed and nothing renamed."""
    paths = [Path(p) for p in paths]
    tmps, fds = [], []
    try:
        for path in paths:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part" + path.suffix, dir=path.parent)
            fds.append(fd)
            tmps.append(Path(tmp))
        yield list(tmps)
        umask = os.umask(0)
        os.umask(umask)
        for tmp, fd in zip(tmps, fds):
            _still_made(tmp, os.fstat(fd))
            os.fchmod(fd, 0o666 & ~umask)
        for tmp, path in zip(tmps, paths):
            os.replace(tmp, path)
    finally:
        for fd in fds:
            os.close(fd)
        for tmp in tmps:
            if os.path.lexists(tmp):
                os.unlink(tmp)


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success."""
    with atomic_paths([path]) as (tmp,):
        yield tmp
