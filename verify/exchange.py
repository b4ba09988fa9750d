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
