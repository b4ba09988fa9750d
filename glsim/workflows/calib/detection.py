"""What every target detector shares: the image as grey levels of full scale, and the
:class:`Detection` it returns."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from glsim.errors import SceneError


@dataclass(frozen=True, eq=False)
class Detection:
    """Dots found in one image, in the target's point order (row-major).

    ``points`` (N, 2) px: refined centres, NaN where a dot was not found or could not be
    measured (its window left the image); ``blobs`` (N, 2) px: the blob centres (corners for
    boards), same order; ``ok`` (N,) bool.
    """
    points: np.ndarray
    blobs: np.ndarray
    ok: np.ndarray


def to_unit(image: np.ndarray, bit_depth: int | None = None) -> np.ndarray:
    """An image as float64 grey levels in [0, 1] of full scale: floats are kept, integers
    divided by 2^bit_depth − 1 (default: 8 for uint8, 16 otherwise)."""
    image = np.asarray(image)
    if image.ndim != 2:
        raise SceneError("image", f"shape {image.shape} is not (H, W)", "give a greyscale image")
    if np.issubdtype(image.dtype, np.floating):
        return image.astype(np.float64)
    bits = bit_depth or (8 if image.dtype == np.uint8 else 16)
    return image.astype(np.float64) / ((1 << bits) - 1)


def to_gray8(image: np.ndarray) -> np.ndarray:
    """A [0, 1] image as 8-bit grey (OpenCV's detectors take these)."""
    return np.clip(np.rint(image * 255), 0, 255).astype(np.uint8)
