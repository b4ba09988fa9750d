"""Figures in README.md and docs/ generated from the results files (``python -m tools.docs [--check]``).

A generated region is delimited in the markdown by

    <!-- generated: NAME from SOURCE[, SOURCE…] -->
    …
    <!-- end generated -->

and its body is what ``GENERATORS[NAME]`` makes of the named results files (paths relative to
the repository). The generators live by topic in tools.docs.accuracy (accuracy, peer, effects),
tools.docs.verify (verify, sweep), tools.docs.calib (calibration) and tools.docs.bench (scaling,
FE, library, preview, quadratic, check), their numbers formatted by ``glsim.bench.formatting``.
``python -m tools.docs`` rewrites every region; ``--check`` (``make readme-check``, part of
``make test``) fails naming each region whose text differs. Timing
figures come first as ratios measured in one run, then absolute times with the machine, which
vary from machine to machine.
"""
from __future__ import annotations

import csv
import difflib
import json
import re
from pathlib import Path

from glsim.errors import GlsimError
from glsim.io import images as io
from tools.docs.accuracy import (accuracy_facts, accuracy_table, effects, effects_camera, effects_dof,
                                 effects_dof_facts, effects_motion, peer, peer_rows)
from tools.docs.bench import (check_drivers, fe_bulge_centre, fe_bulge_centre_5mm, jacobian, library, preview,
                              preview_overhead, quadratic_fast, quadratic_rows, quadratic_tables, scaling_goals,
                              scaling_host, scaling_oracle, scaling_passes, scaling_table, throughput,
                              throughput_change)
from tools.docs.calib import (calibration, calibration_accuracy, calibration_corner_facts, calibration_detection,
                              calibration_estimator_facts, calibration_estimators, calibration_resolution,
                              calibration_spread_facts, calibration_study, calibration_targets, calibration_timing)
from tools.docs.verify import (sweep, sweep_facts, sweep_frontier, sweep_subsets, sweep_table, sweep_timing,
                               verify_choices, verify_facts, verify_runs_table, verify_scale, verify_table,
                               verify_timing)

def markdown_files(root: Path) -> tuple[str, ...]:
    """Every page that may hold a generated region: the README and docs/*.md."""
    return ("README.md",) + tuple(f"docs/{p.name}" for p in sorted((Path(root) / "docs").glob("*.md")))


REGION = re.compile(r"(<!-- generated: (?P<name>[\w-]+) from (?P<sources>[^>]+?) -->\n)(?P<body>.*?)(<!-- end generated -->)",
                    re.S)


GENERATORS = {"check-drivers": check_drivers, "preview": preview, "accuracy-table": accuracy_table, "accuracy-facts": accuracy_facts, "peer": peer,
              "effects": effects, "effects-dof": effects_dof, "effects-dof-facts": effects_dof_facts, "verify-table": verify_table,
              "verify-runs-table": verify_runs_table, "sweep-table": sweep_table, "sweep": sweep, "calibration": calibration,
              "calibration-detection": calibration_detection, "calibration-accuracy": calibration_accuracy,
              "calibration-targets": calibration_targets, "calibration-estimators": calibration_estimators, "library": library,
              "calibration-resolution": calibration_resolution, "calibration-estimator-facts": calibration_estimator_facts,
              "calibration-spread-facts": calibration_spread_facts, "calibration-corner-facts": calibration_corner_facts,
              "calibration-timing": calibration_timing, "calibration-study": calibration_study,
              "verify-scale": verify_scale, "verify-choices": verify_choices, "verify-facts": verify_facts,
              "verify-timing": verify_timing, "sweep-facts": sweep_facts, "sweep-frontier": sweep_frontier,
              "sweep-timing": sweep_timing, "scaling-host": scaling_host, "scaling-oracle": scaling_oracle,
              "scaling-table": scaling_table, "scaling-goals": scaling_goals, "scaling-passes": scaling_passes,
              "preview-overhead": preview_overhead, "fe-bulge-centre": fe_bulge_centre,
              "fe-bulge-centre-5mm": fe_bulge_centre_5mm, "sweep-subsets": sweep_subsets,
              "quadratic-tables": quadratic_tables, "quadratic-rows": quadratic_rows, "quadratic-fast": quadratic_fast,
              "peer-rows": peer_rows, "camera-table": effects_camera, "motion-table": effects_motion,
              "throughput": throughput, "throughput-change": throughput_change, "jacobian": jacobian}


# ---- regions ---------------------------------------------------------------------------------
def render_region(name: str, sources: list[str], root: Path) -> str:
    """The body of one generated region (ending in a newline)."""
    if name not in GENERATORS:
        raise GlsimError(f"generated region {name!r}: unknown; use one of {', '.join(GENERATORS)}")
    data = []
    for s in sources:
        path = root / s
        if not path.is_file():
            raise GlsimError(f"generated region {name!r}: results file {s} not found — run the benchmark that writes it")
        if s.endswith(".csv"):                   # a table of rows: a calibration study's, an FE step's (label;ux;uy;uz)
            with open(path, newline="") as f:
                first = f.readline()
                f.seek(0)
                data.append(list(csv.DictReader(f, delimiter=";" if ";" in first and "," not in first else ",")))
        else:
            data.append(json.loads(path.read_text()))
    return GENERATORS[name](*data).rstrip("\n") + "\n"


def regenerate(text: str, root: Path) -> str:
    """``text`` with every generated region's body made anew from its results files."""
    def sub(m):
        sources = [s.strip() for s in m["sources"].split(",")]
        return m.group(1) + render_region(m["name"], sources, root) + m.group(5)
    return REGION.sub(sub, text)


def check(root: Path, files=None) -> list[str]:
    """A diff per file whose generated regions differ from their results files (empty: all agree)."""
    out = []
    for f in files or markdown_files(root):
        path = root / f
        if not path.is_file():
            continue
        text = path.read_text()
        new = regenerate(text, root)
        if new != text:
            out.append("".join(difflib.unified_diff(text.splitlines(True), new.splitlines(True), f, f + " (generated)")))
    return out


def write(root: Path, files=None) -> list[str]:
    """Rewrite the generated regions in place; the files that changed."""
    changed = []
    for f in files or markdown_files(root):
        path = root / f
        if path.is_file() and (new := regenerate(text := path.read_text(), root)) != text:
            io.write_text(path, new)
            changed.append(f)
    return changed
