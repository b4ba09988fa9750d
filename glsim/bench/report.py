"""What every benchmark and verification report shares: the machine it ran on, the GL renderer,
atomic writing of results files (figures: glsim.workflows.figures)."""
from __future__ import annotations

import os
import platform
from pathlib import Path

from glsim.io import images as io
from glsim.render import Renderer


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (platform.processor() elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info(gl_info: dict) -> dict:
    """Host name, CPU, core count, Python, and the GL vendor/renderer/version."""
    return {"node": platform.node(), "cpu": cpu_model(), "cores": os.cpu_count(),
            "python": platform.python_version(),
            "gl": {k: gl_info[k] for k in ("vendor", "renderer", "version")}}


def machine_line(m: dict) -> str:
    """The machine a results file names, in a few words: CPU, cores, GL renderer."""
    gl = m.get("gl", {})
    return (f"{m.get('cpu', '?')}, {m.get('cores', '?')} cores, {gl.get('renderer', 'no GL')}"
            if isinstance(m, dict) else str(m))


def gl_info(renderer: Renderer) -> dict:
    if renderer.backend_name != "gl":
        return {"vendor": "-", "renderer": "CPU oracle (numpy float64)", "version": "-"}
    from glsim.backends.gl.context import info
    return info(renderer.backend.ctx)


def write_results(report: dict, text: str, out: str | Path, name: str) -> str:
    """``name``.json (the report) and ``name``.md (``text``) written atomically into ``out``; returns ``text``."""
    import json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    io.write_text(out / f"{name}.json", json.dumps(report, indent=2) + "\n")
    io.write_text(out / f"{name}.md", text)
    return text
