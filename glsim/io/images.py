"""Stage "write": quantised images, truth maps and the resolved scene, written atomically
(temporary name in the same directory, then rename), so an interrupted run leaves no
truncated file. An image and its truth maps are written as one group
(:func:`write_image_with_truth`): all under temporary names, then renamed truth first and the
image last, so an image on disk always has its complete truth beside it."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import os
import warnings

import numpy as np

from glsim import limits
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


# ---- image headers: what a file declares, read before it is decoded ----------------------------

@dataclass(frozen=True)
class ImageHeader:
    """What an image file's header declares: width × height px, samples per pixel (1: grey),
    pages (or frames), depth (a volume's slices), and the pixel type (None where not known)."""
    width: int
    height: int
    samples: int = 1
    pages: int = 1
    depth: int = 1
    dtype: np.dtype | None = None

    @property
    def decoded_bytes(self) -> int:
        """Bytes its decoded pixels take (8 per sample where the type is not known)."""
        item = self.dtype.itemsize if self.dtype is not None else 8
        return self.width * self.height * self.samples * self.pages * self.depth * item


_PNG_SAMPLES = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}      # IHDR colour type → samples decoded (palette → RGB)
_PIL_GREY = {"1": np.bool_, "L": np.uint8, "I;16": np.uint16, "I;16B": np.uint16, "I;16L": np.uint16,
             "I;16N": np.uint16, "I": np.int32, "F": np.float32}


def image_header(path: str | Path) -> ImageHeader | None:
    """The header of a PNG, TIFF or other (Pillow-readable) image file, read without decoding its
    pixels; None where it cannot be read (the reader that decodes the file then names the problem)."""
    import logging

    log = logging.getLogger("tifffile")       # it logs a patched header's inconsistencies
    quiet, log.disabled = log.disabled, True
    try:
        with open(path, "rb") as f:
            head = f.read(26)
        if head[:8] == b"\x89PNG\r\n\x1a\n":
            return _png_header(path, head)
        if str(path).lower().endswith((".tif", ".tiff")):
            return _tiff_header(path)
        return _pil_header(path)
    except Exception:  # noqa: BLE001 — the reader that decodes it names the problem
        return None
    finally:
        log.disabled = quiet


def _png_header(path, head: bytes) -> ImageHeader:
    import struct
    W, H = struct.unpack(">II", head[16:24])
    bits, colour = head[24], head[25]
    return ImageHeader(W, H, _PNG_SAMPLES.get(colour, 4), _png_frames(path),
                       dtype=np.dtype(np.uint16 if bits == 16 else np.uint8))


def _png_frames(path) -> int:
    """Frames of a PNG: an animated PNG's acTL chunk (before the first IDAT) says how many."""
    import struct
    with open(path, "rb") as f:
        f.seek(8)
        while True:
            head = f.read(8)
            if len(head) < 8 or head[4:] == b"IDAT":
                return 1
            n = struct.unpack(">I", head[:4])[0]
            if head[4:] == b"acTL":
                return max(1, struct.unpack(">I", f.read(4))[0])
            f.seek(n + 4, 1)                          # the chunk's data and CRC


def _tiff_header(path) -> ImageHeader:
    import tifffile
    with tifffile.TiffFile(path) as tf:
        page = tf.pages.first
        return ImageHeader(page.imagewidth, page.imagelength, page.samplesperpixel, len(tf.pages),
                           page.imagedepth, page.dtype)


def _pil_header(path) -> ImageHeader:
    from PIL import Image
    with Image.open(path) as im:
        W, H = im.size
        grey = im.mode in _PIL_GREY
        return ImageHeader(W, H, 1 if grey else len(im.getbands()), getattr(im, "n_frames", 1),
                           dtype=np.dtype(_PIL_GREY[im.mode]) if grey else None)


def check_image_header(path: str | Path, key: str, what: str, fix: str, max_side: int,
                       dtypes: tuple = (), bytes_per_pixel: int = 0) -> ImageHeader | None:
    """SceneError(key) if the header of the image at ``path`` declares more than ``max_side`` px a
    side (or :data:`~glsim.limits.MAX_IMAGE_PIXELS`), colour, more than one page or slice, a pixel
    type not named in ``dtypes`` (any where empty), or — with ``bytes_per_pixel``, the reader's own
    temporaries per pixel — more memory than :func:`~glsim.limits.memory_budget`: all before a
    pixel is decoded. An unreadable header is left to the reader (None)."""
    from glsim.limits import check_image_size, memory_budget

    h = image_header(path)
    if h is None:
        return None
    check_image_size(key, h.width, h.height, f"{path} (as its header declares)", fix, max_side)
    if h.samples != 1:
        raise SceneError(key, f"{path} is a colour image (its header declares {h.samples} samples per pixel)",
                         f"convert it to a single-channel greyscale {what} before use")
    if h.pages != 1 or h.depth != 1:
        raise SceneError(key, f"{path} is not a single greyscale image (its header declares "
                         f"{h.pages * h.depth} pages or slices)", f"give a single-page, single-channel {what}")
    if dtypes and h.dtype is not None and h.dtype.name not in dtypes:
        raise SceneError(key, f"{path} has unsupported pixel type {h.dtype} (as its header declares)",
                         "save it as 8-bit, 16-bit or float greyscale")
    need = h.decoded_bytes + h.width * h.height * bytes_per_pixel
    budget = memory_budget()
    if bytes_per_pixel and need > budget:
        raise SceneError(key, f"{path} ({h.width} × {h.height} px, as its header declares) needs about "
                         f"{need / 2**30:.3g} GiB to read, more than the {budget / 2**30:.3g} GiB this process may use",
                         fix)
    return h


def check_image_file(path: str | Path, key: str) -> None:
    """SceneError(key) if the reference image file's header declares more pixels than glsim's
    limits, colour, several pages, a pixel type other than 8/16-bit or float, or more memory to read
    than this process may use (REFERENCE_BYTES_PER_PIXEL): read before the image is decoded. An
    unreadable header is left to the reader."""
    check_image_header(path, key, "greyscale image", "give a smaller reference image", limits.MAX_IMAGE_SIDE,
                       limits.REFERENCE_DTYPES, limits.REFERENCE_BYTES_PER_PIXEL)


def load_reference(path, key="speckle.image"):
    """Greyscale reference image from file as float32 (H, W) in [0, 1] of full scale.

    8-bit / 16-bit integer images are scaled by 1/255 / 1/65535; float images are kept
    as they are and must lie in [0, 1]. TIFF files are read with tifffile, others with
    imageio. Colour, multi-page or unreadable files raise SceneError(key, ...) naming the path.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise SceneError(key, f"file not found: {path}",
                         "give an existing image file (path relative to the scene file)")
    check_image_file(path, key)
    import imageio.v3 as iio
    import tifffile

    try:
        if path.lower().endswith((".tif", ".tiff")):
            img = tifffile.imread(path)
        else:
            with warnings.catch_warnings():  # imageio's plugin probing warns about deprecated plugins
                warnings.simplefilter("ignore", DeprecationWarning)
                img = iio.imread(path)
    except Exception as exc:  # any reader failure is a bad input file
        raise SceneError(key, f"cannot read image {path}: {exc}",
                         "give a greyscale TIFF or PNG (8-bit, 16-bit or float)") from None
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[-1] == 1:
        img = img[..., 0]
    if img.ndim == 3 and img.shape[-1] in (2, 3, 4):
        raise SceneError(key, f"{path} is a colour image (shape {img.shape})",
                         "convert it to a single-channel greyscale image before use")
    if img.ndim != 2:
        raise SceneError(key, f"{path} is not a single greyscale image (shape {img.shape})",
                         "give a single-page, single-channel greyscale image")
    if img.dtype == np.uint8:
        return (img / 255.0).astype(np.float32)
    if img.dtype == np.uint16:
        return (img / 65535.0).astype(np.float32)
    if np.issubdtype(img.dtype, np.floating):
        img = img.astype(np.float32)
        if not np.all(np.isfinite(img)):
            raise SceneError(key, f"{path} has NaN or infinite grey levels", "give finite grey levels in [0, 1]")
        if img.min() < 0 or img.max() > 1:
            raise SceneError(key, f"{path} has float grey levels outside [0, 1] "
                             f"(min {img.min():g}, max {img.max():g})",
                             "scale the image to [0, 1] of full scale, or save it as 8- or 16-bit")
        return img
    raise SceneError(key, f"{path} has unsupported pixel type {img.dtype}",
                     "save it as 8-bit, 16-bit or float (in [0, 1]) greyscale")
