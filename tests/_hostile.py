"""What the hostile-input tests share: writing a crafted file (a TIFF whose header lies about its
size), a directory's files (to show that a refusal wrote nothing), a manifest made to vouch for
edited truth files, and running ``glsim`` commands in a child process under an address-space
limit (to show that a refusal comes before a large allocation)."""
from __future__ import annotations

import csv
import hashlib
import json
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np

CAP = 500 << 20   # bytes of address space the child may use: a refusal must come before reading more

_UNDER_CAP = """import contextlib, io, json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({cap}, {cap}))
from glsim.cli import main
out = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            rc = main(argv)
        except BaseException as exc:
            rc = repr(exc)
    out.append([rc, err.getvalue()])
print(json.dumps(out))
"""


def write(path: Path, data) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def files(d: Path) -> dict:
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in d.rglob("*") if p.is_file()}


def main_under_cap(argvs: list[list[str]], cap: int = CAP, timeout: float = 300) -> list[tuple]:
    """``glsim.cli.main(argv)`` for each argv, in one child process limited to ``cap`` bytes of
    address space: (exit status, or the exception's repr; what it printed to stderr) each."""
    r = subprocess.run([sys.executable, "-c", _UNDER_CAP.format(cap=cap), json.dumps(argvs)],
                       capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, r.stderr
    return [tuple(x) for x in json.loads(r.stdout)]


def tiff(path: Path, data: np.ndarray, side: int | None = None, **kw) -> Path:
    """``data`` as a TIFF, its ImageWidth and ImageLength tags patched to ``side`` where given."""
    import tifffile
    tifffile.imwrite(path, data, **kw)
    if side is None:
        return path
    b = bytearray(path.read_bytes())
    ifd = struct.unpack_from("<I", b, 4)[0]
    for i in range(struct.unpack_from("<H", b, ifd)[0]):
        entry = ifd + 2 + 12 * i
        tag, kind = struct.unpack_from("<HH", b, entry)
        if tag in (256, 257):
            struct.pack_into("<H" if kind == 3 else "<I", b, entry + 8, side)
    return write(path, bytes(b))


def vouch(lib: Path) -> None:
    """Make the manifest vouch for the truth files as they are now (size and SHA-256)."""
    with open(lib / "manifest.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    for row in rows:
        data = (lib / row["truth_file"]).read_bytes()
        row["truth_bytes"], row["truth_sha256"] = len(data), hashlib.sha256(data).hexdigest()
    with open(lib / "manifest.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
