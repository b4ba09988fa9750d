"""Stage "vignette": the irradiance's fall-off towards the image corners, a gain per pixel made
in float64 from the camera model (the oracle multiplies by it; shaders/vignette.frag multiplies
by the same gain, uploaded once per camera as float32).

At each pixel centre the undistorted normalized ray (x, y) = (X/Z, Y/Z) of the camera model
gives the chief ray's angle θ to the optical axis, cos θ = 1/√(1 + x² + y²), and the normalized
radius r² = x² + y² (r = tan θ):

    gain = cos⁴θ (natural = true)  ·  (1 + a1·r² + a2·r⁴ + …) (radial = [a1, a2, …])

A pixel with no ray (beyond the distortion model's valid radius) gets gain 0. The gain acts on
the irradiance at the sensor, after pixel integration and depth of field and before the lens
PSF (it varies slowly across a PSF's width, so the order is immaterial there) and the noise.
"""
from __future__ import annotations

import functools

import numpy as np

from glsim.scene.camera import Camera, pixel_grid, pixel_to_normalized, undistort


@functools.lru_cache(maxsize=8)
def gain(cam: Camera, natural: bool, radial: tuple[float, ...]) -> np.ndarray:
    """(H, W) float64 gain of ``cam`` (read-only; cached per camera model)."""
    xn, ok = undistort(pixel_to_normalized(pixel_grid(cam), cam.intrinsics), cam.distortion.coeffs)
    r2 = xn[..., 0] ** 2 + xn[..., 1] ** 2
    g = 1.0 / (1.0 + r2) ** 2 if natural else np.ones(r2.shape)
    if radial:
        g = g * (1.0 + sum(a * r2 ** (k + 1) for k, a in enumerate(radial)))
    g = np.where(ok, g, 0.0)
    g.flags.writeable = False
    return g


def flat_field(cam: Camera, vignetting) -> np.ndarray:
    """The scene's [vignetting] gain of ``cam`` (H, W) float64: the flat-field image."""
    return gain(cam, vignetting.natural, tuple(vignetting.radial))
