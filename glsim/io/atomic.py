"""Atomic writes: files appear under their names complete or not at all (temporary name in the
same directory, then rename), singly or as a group renamed in a chosen order."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path


@contextlib.contextmanager
def atomic_paths(paths):
    """Yield temporary paths next to each of ``paths``; on success rename them onto ``paths``
    in the order given (put the file whose presence marks the group complete last). On any
    exception, KeyboardInterrupt included, every temporary file is removed and nothing renamed."""
    paths = [Path(p) for p in paths]
    tmps = []
    try:
        for path in paths:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part" + path.suffix, dir=path.parent)
            os.close(fd)
            tmps.append(Path(tmp))
        yield list(tmps)
        umask = os.umask(0)
        os.umask(umask)
        for tmp, path in zip(tmps, paths):
            os.chmod(tmp, 0o666 & ~umask)
        for tmp, path in zip(tmps, paths):
            os.replace(tmp, path)
    finally:
        for tmp in tmps:
            if os.path.exists(tmp):
                os.unlink(tmp)


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success."""
    with atomic_paths([path]) as (tmp,):
        yield tmp
