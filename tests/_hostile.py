"""What the hostile-input tests share: writing a crafted file, a directory's files (to show that a
refusal wrote nothing), and running ``glsim`` commands in a child process under an address-space
limit (to show that a refusal comes before a large allocation)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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
