"""Stage "write": quantised images, truth maps and the resolved scene, written atomically
(temporary name in the same directory, then rename), so an interrupted run leaves no
truncated file."""
from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

import numpy as np

from glsim.errors import SceneError

EXTENSIONS = {"tiff": "tif", "png": "png"}


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path next to ``path``; rename it onto ``path`` only on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part" + path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private (0600); use the usual mode
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def quantize(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """Grey levels in [0, 1] of full scale → integers 0 … 2^bits − 1 (round half to even, clipped).

    8-bit images are uint8; 10/12/16-bit images are uint16 holding 0 … 2^bits − 1.
    """
    top = (1 << bit_depth) - 1
    q = np.clip(np.rint(np.asarray(image, np.float64) * top), 0, top)
    return q.astype(np.uint8 if bit_depth == 8 else np.uint16)


def write_image(path: str | Path, image: np.ndarray, bit_depth: int, fmt: str = "tiff") -> Path:
    """Quantise and write one grey image (TIFF or PNG) atomically; returns the path."""
    data = quantize(image, bit_depth)
    path = Path(path)
    with atomic_path(path) as tmp:
        if fmt == "tiff":
            import tifffile
            tifffile.imwrite(tmp, data, photometric="minisblack")
        elif fmt == "png":
            import imageio.v3 as iio
            iio.imwrite(tmp, data, extension=".png")
        else:
            raise SceneError("output.format", f"{fmt!r} is not supported", "use 'tiff' or 'png'")
    return path


def write_truth(path: str | Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write truth maps as one compressed .npz, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return path


def write_truth_tiff(stem: str | Path, arrays: dict[str, np.ndarray]) -> list[Path]:
    """Write each truth map as a float32 TIFF ``{stem}_{name}.tif`` (multi-channel maps as
    (H, W, C); the mask and element index as integers), atomically; returns the paths."""
    import tifffile

    paths = []
    for name, a in arrays.items():
        path = Path(f"{stem}_{name}.tif")
        data = a.astype(np.uint8 if a.dtype == bool else np.int32 if a.dtype.kind == "i" else np.float32)
        with atomic_path(path) as tmp:
            # channels as samples of one page (H, W, C), not as RGB
            tifffile.imwrite(tmp, data, photometric="minisblack", planarconfig="contig" if data.ndim == 3 else None)
        paths.append(path)
    return paths


def write_text(path: str | Path, text: str) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return path


def read_image(path: str | Path) -> np.ndarray:
    """Read back a written image as its stored integers."""
    path = str(path)
    if path.lower().endswith((".tif", ".tiff")):
        import tifffile
        return tifffile.imread(path)
    import imageio.v3 as iio
    return iio.imread(path)
