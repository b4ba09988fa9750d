"""DIC engines behind one small protocol: ``measure(exchange_dir) -> SubsetResults``.

An exchange folder holds what any subset DIC needs and nothing glsim-specific: the reference
image, the deformed images (16-bit TIFF), the ROI (uint8 TIFF, 255 inside), the seed point and the
settings in ``manifest.json``. :class:`Pyvale2D` runs pyvale's 2-D DIC on it as ``glsim verify
sweep`` does: ``verify/dic2d.py`` (manifest format ``glsim-sweep/1``: one sequence, one run) under
the interpreter of ``.venv-verify`` — pyvale pins opencv-python, so it never enters glsim's own
environment. Another engine implements ``name``, ``missing()`` and ``measure()``.
"""
from __future__ import annotations

import json
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import tifffile

from glsim.errors import GlsimError
from glsim.io import images as io
from glsim.io.npzfile import NpzError, read_npz
from glsim.workflows.pyvale_env import PLANAR_SCRIPT as PYVALE_SCRIPT, PYTHON as PYVALE_PYTHON, SETUP_HINT

SHAPES = {"rigid": "RIGID", "affine": "AFFINE", "quad": "QUAD"}
# pyvale.dic.calculate_2d arguments common to every setting: ZNSSD, B-spline interpolation, no
# prefilter (as glsim verify), optimiser tolerance 1e-4, ZNCC threshold 0.9
CALCULATE_2D = {"correlation_criteria": "ZNSSD", "interpolation_routine": "BSPLINE", "image_filter_kernel": 1,
                "precision": 1e-4, "max_iterations": 100, "threshold": 0.9, "output_below_threshold": True}
SEQUENCE, RUN = "r", "run"
MAX_SUBSETS = 10_000_000


@dataclass(frozen=True)
class SubsetResults:
    """One engine call: subset centres (n,) px on the reference image and, per deformed image
    (k, n), the displacement u, v (px), ``valid`` (converged, correlation above the threshold,
    finite) and the correlation coefficient ``cost``; ``seconds`` of the engine's own call."""
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    cost: np.ndarray
    seconds: float
    version: str


class Engine(Protocol):
    name: str

    def missing(self) -> str | None:
        """None where the engine can run here, else what is missing and how to get it."""

    def measure(self, exchange: Path) -> SubsetResults:
        """Measure the exchange folder's deformed images against its reference."""


def write_exchange(out: Path, reference: np.ndarray, deformed: list[np.ndarray], roi: np.ndarray,
                   subset_size: int, subset_step: int, shape_function: str, max_displacement: int) -> Path:
    """The exchange folder (16-bit TIFFs of full-scale images, roi.tif, manifest.json last)."""
    out.mkdir(parents=True, exist_ok=True)
    io.write_image(out / "reference.tif", reference, 16)
    names = []
    for i, img in enumerate(deformed):
        names.append(f"deformed_{i}.tif")
        io.write_image(out / names[-1], img, 16)
    with io.atomic_path(out / "roi.tif") as tmp:
        tifffile.imwrite(tmp, roi.astype(np.uint8) * 255, photometric="minisblack")
    rows, cols = np.nonzero(roi)
    k = int(np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2))
    manifest = {"format": "glsim-sweep/1", "roi": "roi.tif", "seed": [int(cols[k]), int(rows[k])],
                "sequences": [{"name": SEQUENCE, "reference": "reference.tif", "deformed": names}],
                "runs": [{"name": RUN, "subset_size": int(subset_size)}],
                "calculate_2d": {**CALCULATE_2D, "subset_step": int(subset_step),
                                 "shape_function": SHAPES[shape_function],
                                 "max_displacement": int(max_displacement)}}
    return io.write_text(out / "manifest.json", json.dumps(manifest, indent=2))


@dataclass(frozen=True)
class Pyvale2D:
    """pyvale's ``calculate_2d`` through ``verify/dic2d.py`` in ``.venv-verify``."""
    python: Path = PYVALE_PYTHON
    script: Path = PYVALE_SCRIPT
    name: str = "pyvale2d"

    def missing(self) -> str | None:
        if not Path(self.script).is_file():
            return f"{self.script} not found (it lives in the source checkout, not in the wheel)"
        if not Path(self.python).is_file():
            return f"the pyvale environment ({self.python}) is absent: make it with `{SETUP_HINT}`"
        return None

    def measure(self, exchange: Path) -> SubsetResults:
        why = self.missing()
        if why:
            raise GlsimError(f"engine pyvale2d: {why}")
        exchange = Path(exchange).resolve()
        # cwd: pyvale writes plotter_log.log into its working directory, which must be inside -o
        done = subprocess.run([str(Path(self.python).absolute()), str(Path(self.script).resolve()), str(exchange)],
                              cwd=exchange, capture_output=True, text=True)
        if done.returncode != 0:
            tail = (done.stdout + done.stderr).strip().splitlines()[-15:]
            raise GlsimError(f"engine pyvale2d: {self.script} failed with exit status {done.returncode} on "
                             f"{exchange}:\n" + "\n".join(tail))
        path = exchange / f"measured_{SEQUENCE}_{RUN}.npz"
        try:
            m = read_npz(path, ("ss_x", "ss_y", "u", "v", "valid", "cost", "seconds", "pyvale_version"),
                         budget=MAX_SUBSETS * 64)
        except (NpzError, OSError) as exc:
            raise GlsimError(f"engine pyvale2d: {path}: {exc}") from None
        return SubsetResults(x=np.asarray(m["ss_x"], np.float64), y=np.asarray(m["ss_y"], np.float64),
                             u=np.atleast_2d(m["u"]), v=np.atleast_2d(m["v"]), valid=np.atleast_2d(m["valid"]),
                             cost=np.atleast_2d(m["cost"]), seconds=float(m["seconds"]),
                             version=str(m["pyvale_version"]))


def engine(name: str) -> Engine:
    if name == "pyvale2d":
        return Pyvale2D()
    raise GlsimError(f"engine: {name!r} is not an engine (pyvale2d)")
