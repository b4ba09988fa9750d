"""Stage "write": quantised images, truth maps and the resolved scene, written atomically
(temporary name in the same directory, then rename), so an interrupted run leaves no
truncated file. An image and its truth maps are written as one group
(:func:`write_image_with_truth`): all under temporary names, then renamed truth first and the
image last, so an image on disk always has its complete truth beside it."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from glsim.errors import SceneError
from glsim.io.atomic import atomic_path, atomic_paths

EXTENSIONS = {"tiff": "tif", "png": "png"}
TRUTH_FORMATS = ("npz", "tiff", "tiff64", "vtk")   # tiff: float32 maps; tiff64: float64; vtk: one .vti


def quantize(image: np.ndarray, bit_depth: int) -> np.ndarray:
    """Grey levels in [0, 1] of full scale → integers 0 … 2^bits − 1 (round half to even, clipped).

    8-bit images are uint8; 10/12/16-bit images are uint16 holding 0 … 2^bits − 1. An image
    already quantised (``Renderer.render(..., quantize=True)``: unsigned integers of that type) is
    returned as it is.
    """
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    if getattr(image, "dtype", None) == dtype:
        return image
    top = (1 << bit_depth) - 1
    q = np.clip(np.rint(np.asarray(image, np.float64) * top), 0, top)
    return q.astype(dtype)


def saturated_fraction(image: np.ndarray, covered: np.ndarray, bit_depth: int) -> float:
    """Fraction of the specimen's pixels (``covered``) below 0 or above full scale — of a
    quantised image, at 0 or 2^bits − 1 —; the background is not counted."""
    n = np.count_nonzero(covered)
    if image.dtype.kind == "u":
        clipped = (image == 0) | (image == (1 << bit_depth) - 1)
    elif n and (image.min() < 0 or image.max() > 1):   # (the extremes first: most images have none)
        clipped = (image < 0) | (image > 1)
    else:
        return 0.0
    return float(np.count_nonzero(clipped & covered) / n) if n else 0.0


def _image_file(tmp: Path, data: np.ndarray, fmt: str) -> None:
    if fmt == "tiff":
        import tifffile
        tifffile.imwrite(tmp, data, photometric="minisblack")
    elif fmt == "png":
        import imageio.v3 as iio
        iio.imwrite(tmp, data, extension=".png")
    else:
        raise SceneError("output.format", f"{fmt!r} is not supported", "use 'tiff' or 'png'")


def write_image(path: str | Path, image: np.ndarray, bit_depth: int, fmt: str = "tiff") -> Path:
    """Quantise and write one grey image (TIFF or PNG) atomically; returns the path."""
    data = quantize(image, bit_depth)
    path = Path(path)
    with atomic_path(path) as tmp:
        _image_file(tmp, data, fmt)
    return path


def _npz_file(tmp: Path, arrays: dict[str, np.ndarray]) -> None:
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)


def write_truth(path: str | Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write truth maps as one compressed .npz, atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        _npz_file(tmp, arrays)
    return path


TRUTH_TIFF_DTYPES = ("float32", "float64")


def _tiff_map(tmp: Path, a: np.ndarray, float_dtype: str = "float32") -> None:
    import tifffile
    data = a.astype(np.uint8 if a.dtype == bool else np.int32 if a.dtype.kind == "i" else float_dtype)
    # channels as samples of one page (H, W, C), not as RGB
    tifffile.imwrite(tmp, data, photometric="minisblack", planarconfig="contig" if data.ndim == 3 else None)


def truth_tiff_paths(stem: str | Path, names) -> list[Path]:
    """The files :func:`write_truth_tiff` writes for the maps ``names``."""
    return [Path(f"{stem}_{name}.tif") for name in names]


def write_truth_tiff(stem: str | Path, arrays: dict[str, np.ndarray], float_dtype: str = "float32") -> list[Path]:
    """Write each truth map as a float TIFF ``{stem}_{name}.tif`` (float32 by default, or
    ``float_dtype="float64"``; multi-channel maps as (H, W, C); the mask and element index as
    integers), atomically as one group; returns the paths."""
    paths = truth_tiff_paths(stem, arrays)
    with atomic_paths(paths) as tmps:
        for tmp, a in zip(tmps, arrays.values()):
            _tiff_map(tmp, a, float_dtype)
    return paths


def truth_paths(image_path: str | Path, names, truth_format: str = "npz") -> list[Path]:
    """The truth files that go with ``image_path``: ``{stem}_truth.npz`` (or ``.vti`` for "vtk"),
    or for ``truth_format`` "tiff"/"tiff64" one ``{stem}_truth_{name}.tif`` per map in ``names``."""
    p = Path(image_path)
    if truth_format in ("npz", "vtk"):
        return [p.with_name(p.stem + ("_truth.npz" if truth_format == "npz" else "_truth.vti"))]
    return truth_tiff_paths(p.with_name(p.stem + "_truth"), names)


def write_image_with_truth(path: str | Path, image: np.ndarray, bit_depth: int, fmt: str = "tiff",
                           truth: dict[str, np.ndarray] | None = None,
                           truth_format: str = "npz") -> tuple[Path, list[Path]]:
    """Write an image and its truth maps together or not at all: every file under a
    temporary name first, then renamed truth first and the image last (so an image on disk
    always has its whole truth). ``truth_format``: "npz" (one compressed file, float64),
    "tiff" (one float32 TIFF per map), "tiff64" (float64 TIFFs) or "vtk" (one ParaView ImageData
    ``.vti``, :mod:`glsim.io.vtkfiles`). Returns (image, truth paths)."""
    if truth_format not in TRUTH_FORMATS:
        raise SceneError("truth_format", f"{truth_format!r} is not one of {TRUTH_FORMATS}",
                         f"use one of {', '.join(TRUTH_FORMATS)}")
    data = quantize(image, bit_depth)
    path = Path(path)
    tpaths = truth_paths(path, truth or {}, truth_format) if truth is not None else []
    with atomic_paths([*tpaths, path]) as tmps:
        if truth is not None and truth_format == "npz":
            _npz_file(tmps[0], truth)
        elif truth is not None and truth_format == "vtk":
            from glsim.io.vtkfiles import write_vti_file
            write_vti_file(tmps[0], truth)
        elif truth is not None:
            dtype = "float64" if truth_format == "tiff64" else "float32"
            for tmp, a in zip(tmps, truth.values()):
                _tiff_map(tmp, a, dtype)
        _image_file(tmps[-1], data, fmt)
    return path, tpaths


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
