"""Refactors of the renderer keep its bytes: images, truth and a Jacobian of a fixed set of scenes
(bench/same_bytes.py) hash as recorded before the refactor. The hashes hold on the machine that
recorded them (llvmpipe's code follows the CPU), so elsewhere the test says so and skips."""
import importlib.util
from pathlib import Path

import pytest

pytestmark = [pytest.mark.gl, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]


def _tool():
    spec = importlib.util.spec_from_file_location("same_bytes", ROOT / "bench" / "same_bytes.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_fixed_scenes_render_the_recorded_bytes():
    import json

    tool = _tool()
    if not tool.FIXTURE.exists():
        pytest.skip(f"no fixture for pixel stage {tool.STAGE}")
    want = json.loads(tool.FIXTURE.read_text())
    here = tool.machine()
    if want["machine"] != here:
        pytest.skip(f"fixture recorded on {want['machine']}, this machine is {here}")
    got = tool.record_hashes()
    changed = sorted(k for k, v in want["hashes"].items() if got.get(k) != v)
    assert not changed, f"{len(changed)} of {len(want['hashes'])} hashes changed: {changed[:10]}"
