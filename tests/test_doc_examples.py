"""Every ```python block of README.md and docs/*.md runs as written: each in a fresh interpreter,
in a temporary directory where the repository's `examples/` is at hand (the docs' paths are
relative to the checkout). A block marked in the markdown, on the line before its fence, with

    <!-- not-run: why -->    is only compiled (kept few: NOT_RUN_MAX);
    <!-- needs: NAME -->     runs after the test has made NAME in its directory (SETUPS).

A block whose code uses no renderer runs with EGL unable to find a driver, so one that needs GL
and is not taken as drawing here fails rather than passing only where a GPU or llvmpipe happens
to be; a test is marked `gl` where its block or its setup draws."""
from __future__ import annotations

import ast
import importlib.util
import os
import re
import subprocess
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

import pytest

pytestmark = [pytest.mark.workflow, pytest.mark.tools]   # the compute-stage rerun of the GL tier leaves these out (docs/testing.md)

ROOT = Path(__file__).resolve().parents[1]
FILES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```python[ \t]*\n(.*?)^```", re.S | re.M)
MARK = re.compile(r"<!--\s*(not-run|needs):\s*(.*?)\s*-->")
# what draws through a renderer (the GL backend by default)
GL_USE = re.compile(r"\b(Renderer|Preview|Widget|calib|render)\b")
NOT_RUN_MAX = 2
TIMEOUT_S = 600


@dataclass(frozen=True)
class Block:
    file: str
    line: int
    code: str
    not_run: str | None = None
    needs: str | None = None

    @property
    def id(self) -> str:
        return f"{self.file}:{self.line}"

    @property
    def draws(self) -> bool:
        """Whether the block's own code renders (else it runs with no EGL driver to find)."""
        return bool(GL_USE.search(self.code))

    @property
    def gl(self) -> bool:
        """Whether the test needs GL: the block draws, or its setup does (every setup renders)."""
        return self.draws or self.needs is not None


def find_blocks() -> list[Block]:
    """The python blocks of the docs, each with the marker on the line before its fence."""
    blocks = []
    for path in FILES:
        text = path.read_text()
        for m in FENCE.finditer(text):
            line = text.count("\n", 0, m.start()) + 1
            before = text[:m.start()].rstrip("\n").rsplit("\n", 1)[-1]
            mark = MARK.fullmatch(before.strip())
            kind, value = (mark[1], mark[2]) if mark else (None, None)
            blocks.append(Block(path.relative_to(ROOT).as_posix(), line, m[1],
                                value if kind == "not-run" else None, value if kind == "needs" else None))
    return blocks


BLOCKS = find_blocks()


def _noise_lib(cwd: Path) -> None:
    """`noise-lib`: docs/library.md's `glsim library examples/library_noise.toml -o noise-lib`
    cut down to two of its noise levels and camera 0 (the bulge's steps 0 and 3, compact truth)."""
    (cwd / "spec.toml").write_text(textwrap.dedent("""\
        scene = "examples/bulge.toml"
        cameras = ["cam0"]
        steps = [0, 3]
        [vary]
        noise.sigma = [1.0, 2.0]
        """))
    done = subprocess.run([sys.executable, "-m", "glsim.cli", "library", "spec.toml", "-o", "noise-lib",
                           "--workers", "1"], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S)
    assert done.returncode == 0, done.stdout + done.stderr


SETUPS = {"noise-lib": _noise_lib}


def test_the_docs_have_python_blocks_and_few_are_not_run():
    assert len(BLOCKS) >= 8, [b.id for b in BLOCKS]
    assert any(b.file == "README.md" for b in BLOCKS)
    not_run = [b for b in BLOCKS if b.not_run is not None]
    assert len(not_run) <= NOT_RUN_MAX, [(b.id, b.not_run) for b in not_run]
    assert all(b.not_run for b in not_run), "a not-run marker says why"
    assert {b.needs for b in BLOCKS} - {None} <= set(SETUPS), "a needs marker names a setup this test makes"


@pytest.mark.parametrize("block", BLOCKS, ids=lambda b: b.id)
def test_every_block_compiles(block):
    compile(block.code, block.id, "exec", ast.PyCF_ONLY_AST)


@pytest.mark.process
@pytest.mark.parametrize("block", [pytest.param(b, id=b.id, marks=[pytest.mark.gl] if b.gl else [])
                                   for b in BLOCKS if b.not_run is None])
def test_every_block_runs(block, tmp_path):
    for name in re.findall(r"^\s*(?:import|from)\s+(\w+)", block.code, re.M):
        if importlib.util.find_spec(name) is None:   # an optional extra (pandas: glsim[library])
            pytest.skip(f"{block.id} imports {name}, which is not installed")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    if block.needs:
        SETUPS[block.needs](tmp_path)
    (tmp_path / "example.py").write_text(block.code)
    env = {**os.environ, "MPLBACKEND": "Agg"}
    if not block.draws:   # (libglvnd then finds no EGL driver)
        env["__EGL_VENDOR_LIBRARY_FILENAMES"] = str(tmp_path / "no-egl-vendor.json")
    done = subprocess.run([sys.executable, "example.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=TIMEOUT_S)
    assert done.returncode == 0, f"{block.id} failed:\n{done.stderr[-3000:]}"
