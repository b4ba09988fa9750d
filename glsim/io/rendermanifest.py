"""What a render wrote: ``render-manifest.jsonl`` in its output directory, one JSON line per file
(``{"file": NAME, "bytes": N, "sha256": HEX}``, the name relative to the directory), appended
after each image and its truth are renamed into place. A resumed render keeps a file only if its
size and SHA-256 match its last line here; anything else — a file glsim did not record, a
truncated or edited one — is rendered again. Appending keeps the cost of a record constant;
a line cut short (a kill, a full disk) is skipped when read, so its files are rendered again.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
from pathlib import Path

from glsim.errors import SceneError
from glsim.io import atomic

NAME = "render-manifest.jsonl"
MAX_BYTES = 1 << 28          # 256 MiB: ~2 million records; read line by line, each at most LINE_MAX
LINE_MAX = 4096
_HEX = re.compile(r"[0-9a-f]{64}")
FIX = f"remove it ({NAME} is glsim's record of what it wrote: without it the files are rendered again)"


def sha256(path: Path) -> str:
    """The digest of the regular file at ``path`` (opened without following a link)."""
    h = hashlib.sha256()
    fd = atomic.open_regular(path, os.O_RDONLY, "remove it, or write to another directory (-o)", one_link=False)
    with os.fdopen(fd, "rb") as f:
        while block := f.read(1 << 20):
            h.update(block)
    return h.hexdigest()


def _lines(f):
    """The lines of ``f`` of at most LINE_MAX bytes (longer ones skipped without being held)."""
    while line := f.readline(LINE_MAX + 1):
        if len(line) <= LINE_MAX:
            yield line
            continue
        while line and not line.endswith(b"\n"):
            line = f.readline(LINE_MAX + 1)


def _record(line: bytes):
    """(file, (bytes, sha256)) of a well-formed line, else None."""
    try:
        rec = json.loads(line)
    except ValueError:
        return None
    if not isinstance(rec, dict):
        return None
    name, size, digest = rec.get("file"), rec.get("bytes"), rec.get("sha256")
    if (isinstance(name, str) and isinstance(size, int) and not isinstance(size, bool) and size >= 0
            and isinstance(digest, str) and _HEX.fullmatch(digest)):
        return name, (size, digest)
    return None


def read(out: Path, wanted) -> dict[str, tuple[int, str]]:
    """File name → (bytes, sha256): the last record of each name in ``wanted`` ({} without a
    manifest). SceneError naming the manifest if it is not a regular file or is over MAX_BYTES."""
    path = out / NAME
    if not os.path.lexists(path):
        return {}
    wanted, records = set(wanted), {}
    with os.fdopen(atomic.open_regular(path, os.O_RDONLY, FIX), "rb") as f:
        size = os.fstat(f.fileno()).st_size
        if size > MAX_BYTES:
            raise SceneError(str(path), f"is {size:,} bytes, more than glsim's limit of {MAX_BYTES:,} for it", FIX)
        for line in _lines(f):
            rec = _record(line)
            if rec is not None and rec[0] in wanted:
                records[rec[0]] = rec[1]
    return records


def mismatch(path: Path, record) -> str:
    """Why the file at ``path`` does not match its ``record`` (bytes, sha256); "" if it does."""
    if record is None:
        return f"not in {NAME}"
    size = os.lstat(path).st_size
    if size != record[0]:
        return f"{size:,} bytes, {record[0]:,} recorded"
    return "" if sha256(path) == record[1] else "its SHA-256 is not the one recorded"


@contextlib.contextmanager
def appending(out: Path):
    """``record(paths)`` for the block: appends a line per file (its name relative to ``out``,
    size and SHA-256, read back from the disk) in one write."""
    fd = atomic.open_regular(out / NAME, os.O_RDWR | os.O_APPEND | os.O_CREAT, FIX)
    try:
        end = os.fstat(fd).st_size
        if end and os.pread(fd, 1, end - 1) != b"\n":     # a line cut short: it stays unreadable alone
            _write_all(fd, b"\n")

        def record(paths) -> None:
            lines = [json.dumps({"file": Path(p).relative_to(out).as_posix(), "bytes": os.lstat(p).st_size,
                                 "sha256": sha256(Path(p))}) + "\n" for p in paths]
            _write_all(fd, "".join(lines).encode())

        yield record
    finally:
        os.close(fd)


def _write_all(fd: int, data: bytes) -> None:
    while data:
        data = data[os.write(fd, data):]
