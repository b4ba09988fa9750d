"""Shared by the effect examples: a side-by-side PNG of an image and the effect's change,
in a blue (brighter) / red (darker) diverging map like the paper's Fig. 5."""
import numpy as np


def diverging(delta: np.ndarray, limit: float) -> np.ndarray:
    """RGB uint8 of ``delta``: blue where positive, red where negative, white at 0."""
    t = np.clip(delta / limit, -1, 1)[..., None]
    white = np.ones(delta.shape + (3,))
    blue, red = np.array([0.1, 0.3, 1.0]), np.array([1.0, 0.15, 0.1])
    rgb = np.where(t > 0, white + t * (blue - white), white - t * (red - white))
    return (rgb * 255).astype(np.uint8)


def figure(path: str, image: np.ndarray, delta: np.ndarray) -> None:
    """Write the image (grey) and its change (diverging, scaled to the largest |change|)."""
    import imageio.v3 as iio

    grey = np.repeat((np.clip(image, 0, 1) * 255).astype(np.uint8)[..., None], 3, axis=-1)
    limit = float(np.abs(delta).max()) or 1.0
    gap = np.full((image.shape[0], 8, 3), 255, np.uint8)
    iio.imwrite(path, np.hstack([grey, gap, diverging(delta, limit)]))
    print(f"wrote {path} (change up to {limit * 255:.1f} grey levels of 8 bit)")
