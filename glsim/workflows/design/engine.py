"""DIC engines behind one small protocol: ``measure(exchange_dir) -> SubsetResults``.

An exchange folder holds what any subset DIC needs and nothing glsim-specific: the reference
image, the deformed images (16-bit TIFF), the ROI (uint8 TIFF, 255 inside), the seed point and the
settings in ``manifest.json``. :class:`Pyvale2D` runs pyvale's 2-D DIC on it as ``glsim verify
sweep`` does: ``verify/dic2d.py`` (manifest format ``glsim-sweep/1``: one sequence, one run) under
the interpreter of ``.venv-verify`` — pyvale pins opencv-python, so it never enters glsim's own
environment. :class:`Pyvale3D` runs pyvale's stereo DIC (``calculate_3d``) on a stereo exchange
folder through ``verify/dic.py``, the script of ``glsim verify``, in the same environment. Another
engine implements ``name``, ``missing()`` and ``measure()``.
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
from glsim.workflows.pyvale_env import STEREO_SCRIPT

SHAPES = {"rigid": "RIGID", "affine": "AFFINE", "quad": "QUAD"}
# pyvale.dic.calculate_2d arguments common to every setting: ZNSSD, B-spline interpolation, no
# prefilter (as glsim verify), optimiser tolerance 1e-4, ZNCC threshold 0.9
CALCULATE_2D = {"correlation_criteria": "ZNSSD", "interpolation_routine": "BSPLINE", "image_filter_kernel": 1,
                "precision": 1e-4, "max_iterations": 100, "threshold": 0.9, "output_below_threshold": True}
SEQUENCE, RUN = "r", "run"
MAX_SUBSETS = 10_000_000


def run_script(engine, exchange: Path) -> Path:
    """Run ``engine.script`` on the exchange folder under ``engine.python`` (pyvale's environment);
    GlsimError naming the engine with what is missing, or with the script's last lines if it fails.
    Its working directory is the exchange folder: pyvale writes plotter_log.log there, inside -o."""
    why = engine.missing()
    if why:
        raise GlsimError(f"engine {engine.name}: {why}")
    exchange = Path(exchange).resolve()
    done = subprocess.run([str(Path(engine.python).absolute()), str(Path(engine.script).resolve()), str(exchange)],
                          cwd=exchange, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stdout + done.stderr).strip().splitlines()[-15:]
        raise GlsimError(f"engine {engine.name}: {engine.script} failed with exit status {done.returncode} on "
                         f"{exchange}:\n" + "\n".join(tail))
    return exchange


@dataclass(frozen=True)
class SubsetResults:
    """One engine call: subset centres (n,) px on the reference image and, per deformed image
    (k, n), the displacement u, v (px), ``valid`` (converged, correlation above the threshold,
    finite) and the correlation coefficient ``cost``; ``seconds`` of the engine's own call. With
    strain asked for (:func:`write_exchange`'s ``strain``): the strain points ``strain_x``,
    ``strain_y`` (m,) px on the reference image and per deformed image (k, m) the in-plane strain
    ``exx``, ``eyy``, ``exy`` (tensor shear, the formulation asked for) and ``strain_valid``."""
    x: np.ndarray
    y: np.ndarray
    u: np.ndarray
    v: np.ndarray
    valid: np.ndarray
    cost: np.ndarray
    seconds: float
    version: str
    strain_x: np.ndarray | None = None
    strain_y: np.ndarray | None = None
    exx: np.ndarray | None = None
    eyy: np.ndarray | None = None
    exy: np.ndarray | None = None
    strain_valid: np.ndarray | None = None


STRAIN_ARRAYS = ("strain_x", "strain_y", "exx", "eyy", "exy", "strain_valid")


class Engine(Protocol):
    name: str

    def missing(self) -> str | None:
        """None where the engine can run here, else what is missing and how to get it."""

    def measure(self, exchange: Path) -> SubsetResults:
        """Measure the exchange folder's deformed images against its reference."""


def write_exchange(out: Path, reference: np.ndarray, deformed: list[np.ndarray], roi: np.ndarray,
                   subset_size: int, subset_step: int, shape_function: str, max_displacement: int,
                   strain: dict | None = None) -> Path:
    """The exchange folder (16-bit TIFFs of full-scale images, roi.tif, manifest.json last);
    ``strain``: pyvale.strain.calculate_2d's ``window_size``, ``window_element`` and
    ``strain_formulation``, or None (no strain: the manifest as before)."""
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
    if strain:
        manifest["strain"] = _strain_table(strain)
    return io.write_text(out / "manifest.json", json.dumps(manifest, indent=2))


def _strain_table(strain: dict) -> dict:
    """The manifest's ``strain`` table: pyvale.strain.calculate_2d / _3d's keyword arguments."""
    return {"window_size": int(strain["window_size"]), "window_element": int(strain["window_element"]),
            "strain_formulation": str(strain["strain_formulation"])}


def _read_strain(m: dict, path: Path, name: str) -> dict:
    """The optional strain arrays of a measured npz (all or none), checked against each other."""
    if not all(k in m for k in STRAIN_ARRAYS):
        return {}
    strain = {"strain_x": np.asarray(m["strain_x"], np.float64), "strain_y": np.asarray(m["strain_y"], np.float64),
              **{k: np.atleast_2d(np.asarray(m[k], np.float64)) for k in ("exx", "eyy", "exy")},
              "strain_valid": np.atleast_2d(m["strain_valid"]).astype(bool)}
    n = len(strain["strain_x"])
    if strain["strain_y"].shape != (n,) or any(strain[k].shape[-1] != n for k in STRAIN_ARRAYS[2:]):
        raise GlsimError(f"engine {name}: {path}: the strain arrays' lengths differ from strain_x's ({n})")
    return strain


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
        exchange = run_script(self, exchange)
        path = exchange / f"measured_{SEQUENCE}_{RUN}.npz"
        try:
            m = read_npz(path, ("ss_x", "ss_y", "u", "v", "valid", "cost", "seconds", "pyvale_version"),
                         optional=STRAIN_ARRAYS, budget=MAX_SUBSETS * 128)
        except (NpzError, OSError) as exc:
            raise GlsimError(f"engine pyvale2d: {path}: {exc}") from None
        strain = _read_strain(m, path, self.name)
        return SubsetResults(x=np.asarray(m["ss_x"], np.float64), y=np.asarray(m["ss_y"], np.float64),
                             u=np.atleast_2d(m["u"]), v=np.atleast_2d(m["v"]), valid=np.atleast_2d(m["valid"]),
                             cost=np.atleast_2d(m["cost"]), seconds=float(m["seconds"]),
                             version=str(m["pyvale_version"]), **strain)


# ---- stereo ------------------------------------------------------------------------------------------
STEREO_RUN, STEREO_BITS = "run", 16
# pyvale.dic.calculate_3d arguments common to every setting: those of calculate_2d above (the
# temporal and the stereo matches alike); the epipolar search keeps pyvale's defaults
CALCULATE_3D = {k: v for k, v in CALCULATE_2D.items()}


@dataclass(frozen=True)
class StereoResults:
    """One stereo engine call: subset centres (n,) px on camera 0's reference image and, per state
    of the exchange (k, n; state 0 the reference): positions X, Y, Z and displacements from the
    reference U, V, W (mm, camera 0's frame), ``valid`` (converged and above the threshold in the
    temporal and stereo matches, finite), the temporal correlation ``cost``; ``seconds`` of the
    engine's own call. With strain asked for: strain points and per state the surface strain, as
    :class:`SubsetResults`'s (pyvale's tangent basis: camera 0's x projected onto the surface)."""
    x: np.ndarray
    y: np.ndarray
    X: np.ndarray
    Y: np.ndarray
    Z: np.ndarray
    U: np.ndarray
    V: np.ndarray
    W: np.ndarray
    valid: np.ndarray
    cost: np.ndarray
    seconds: float
    version: str
    strain_x: np.ndarray | None = None
    strain_y: np.ndarray | None = None
    exx: np.ndarray | None = None
    eyy: np.ndarray | None = None
    exy: np.ndarray | None = None
    strain_valid: np.ndarray | None = None


class StereoEngine(Protocol):
    name: str

    def missing(self) -> str | None:
        """None where the engine can run here, else what is missing and how to get it."""

    def measure(self, exchange: Path) -> StereoResults:
        """Measure the stereo exchange folder's states against its reference pair."""


def stereo_image_name(camera: int, state: int) -> str:
    return f"cam{camera}_{state:04d}_{STEREO_BITS}bit.tif"


def write_stereo_exchange(out: Path, states: list[tuple[np.ndarray, np.ndarray]], roi: np.ndarray,
                          calibration: dict, subset_size: int, subset_step: int, shape_function: str,
                          max_displacement: int, strain: dict | None = None) -> Path:
    """A stereo exchange folder in ``glsim verify``'s format (verify/dic.py reads it): per state a
    camera-0 and a camera-1 image (16-bit TIFF of full-scale images; state 0 the reference),
    roi.tif on camera 0's reference image, calibration.json (pyvale's ``Calib`` fields) and
    manifest.json last."""
    out.mkdir(parents=True, exist_ok=True)
    manifest_states = []
    for k, pair in enumerate(states):
        names = [stereo_image_name(c, k) for c in (0, 1)]
        for name, img in zip(names, pair):
            io.write_image(out / name, img, STEREO_BITS)
        manifest_states.append({"state": k, "images": {str(STEREO_BITS): names}})
    with io.atomic_path(out / "roi.tif") as tmp:
        tifffile.imwrite(tmp, roi.astype(np.uint8) * 255, photometric="minisblack")
    io.write_text(out / "calibration.json", json.dumps(calibration, indent=2))
    rows, cols = np.nonzero(roi)
    k = int(np.argmin((rows - rows.mean()) ** 2 + (cols - cols.mean()) ** 2))
    manifest = {"format": "glsim-design-stereo/1", "states": manifest_states, "roi": "roi.tif",
                "seed": [int(cols[k]), int(rows[k])], "calibration": "calibration.json",
                "calculate_3d": {**CALCULATE_3D, "subset_size": int(subset_size), "subset_step": int(subset_step),
                                 "max_displacement": int(max_displacement)},
                "runs": [{"name": STEREO_RUN, "shape_function": SHAPES[shape_function], "bit_depth": STEREO_BITS}]}
    if strain:
        manifest["strain"] = _strain_table(strain)
    return io.write_text(out / "manifest.json", json.dumps(manifest, indent=2))


@dataclass(frozen=True)
class Pyvale3D:
    """pyvale's ``calculate_3d`` through ``verify/dic.py`` (``glsim verify``'s script) in ``.venv-verify``."""
    python: Path = PYVALE_PYTHON
    script: Path = STEREO_SCRIPT
    name: str = "pyvale3d"

    def missing(self) -> str | None:
        return Pyvale2D(python=self.python, script=self.script).missing()

    def measure(self, exchange: Path) -> StereoResults:
        exchange = run_script(self, exchange)
        path = exchange / f"measured_{STEREO_RUN}.npz"
        try:
            m = read_npz(path, ("ss_x", "ss_y", "X", "U", "valid", "cost", "seconds", "pyvale_version"),
                         optional=STRAIN_ARRAYS, budget=MAX_SUBSETS * 256)
        except (NpzError, OSError) as exc:
            raise GlsimError(f"engine pyvale3d: {path}: {exc}") from None
        X, U = np.asarray(m["X"], np.float64), np.asarray(m["U"], np.float64)
        if X.ndim != 3 or X.shape[-1] != 3 or U.shape != X.shape:
            raise GlsimError(f"engine pyvale3d: {path}: X and U are {X.shape} and {U.shape}, not (states, n, 3)")
        return StereoResults(x=np.asarray(m["ss_x"], np.float64), y=np.asarray(m["ss_y"], np.float64),
                             X=X[..., 0], Y=X[..., 1], Z=X[..., 2], U=U[..., 0], V=U[..., 1], W=U[..., 2],
                             valid=np.atleast_2d(m["valid"]).astype(bool), cost=np.atleast_2d(m["cost"]),
                             seconds=float(m["seconds"]), version=str(m["pyvale_version"]),
                             **_read_strain(m, path, self.name))


def engine(name: str) -> Engine | StereoEngine:
    if name == "pyvale2d":
        return Pyvale2D()
    if name == "pyvale3d":
        return Pyvale3D()
    raise GlsimError(f"engine: {name!r} is not an engine (pyvale2d, pyvale3d)")
