"""Exchange-folder helpers shared by verify/dic.py and verify/dic2d.py (they run in
.venv-verify with pyvale and never import glsim; Python puts this folder on their path)."""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from PIL import Image


def save_npz(path: Path, arrays: dict) -> None:
    """Write ``arrays`` to ``path`` under a temporary name, then rename (atomic)."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part.npz", dir=path.parent)
    with open(fd, "wb") as f:
        np.savez(f, **arrays)
    Path(tmp).replace(path)


def load_roi(exchange: Path, manifest: dict) -> np.ndarray:
    """The manifest's ROI image as a boolean mask."""
    return np.asarray(Image.open(exchange / manifest["roi"])) > 0


def fresh_dir(path: Path) -> Path:
    """``path`` created if missing, emptied of earlier pyvale CSV results."""
    path.mkdir(parents=True, exist_ok=True)
    for old in path.glob("*.csv"):
        old.unlink()
    return path


def valid_on_grid(ss_x, ss_y, m: dict, shape) -> np.ndarray:
    """(states, rows, cols) bool: pyvale's matrix-layout grid (ss_x's first row, ss_y's first column)
    True at the subsets valid in ``m`` (ss_x, ss_y, valid per state) — the rest set to NaN before
    strain, so that no strain window uses a subset that did not converge."""
    cols = np.searchsorted(ss_x[0], m["ss_x"])
    rows = np.searchsorted(ss_y[:, 0], m["ss_y"])
    keep = np.zeros(shape, bool)
    for k in range(shape[0]):
        keep[k, rows[m["valid"][k]], cols[m["valid"][k]]] = True
    return keep


def strain_arrays(out: Path, prefix: str, states: int, importer) -> dict:
    """pyvale's strain CSVs (one per state) read back with ``importer`` (pyvale.strain.import_2d or
    import_3d) as the measured npz's strain arrays: window centres, exx, eyy, exy, strain_valid."""
    import contextlib
    import io
    written = [out / f"{prefix}strain_data_{k:04d}.csv" for k in range(states)]
    missing = [str(f) for f in written if not f.is_file()]
    if missing:
        raise RuntimeError(f"pyvale's strain wrote no result for {missing} (found {sorted(p.name for p in out.glob('*'))})")
    with contextlib.redirect_stdout(io.StringIO()):
        res = importer(written, delimiter=",", layout="column")
    exx, eyy, exy = (np.atleast_2d(np.asarray(a, np.float64)) for a in (res.eps_xx, res.eps_yy, res.eps_xy))
    ok = np.isfinite(exx) & np.isfinite(eyy) & np.isfinite(exy)
    return {"strain_x": np.asarray(res.window_x, np.float64).ravel(), "strain_y": np.asarray(res.window_y, np.float64).ravel(),
            "exx": exx, "eyy": eyy, "exy": exy, "strain_valid": ok}
