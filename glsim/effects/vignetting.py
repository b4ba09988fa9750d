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
    g = np.where(ok, _falloff(xn[..., 0] ** 2 + xn[..., 1] ** 2, natural, radial)[0], 0.0)
    g.flags.writeable = False
    return g


def _falloff(r2, natural: bool, radial: tuple[float, ...]):
    """The gain at squared normalized radii ``r2`` and its derivative in r²: cos⁴θ = 1/(1 + r²)²
    (``natural``) times 1 + a1·r² + a2·r⁴ + … (``radial``)."""
    f, df = (1.0 / (1.0 + r2) ** 2, -2.0 / (1.0 + r2) ** 3) if natural else (np.ones(r2.shape), np.zeros(r2.shape))
    if not radial:
        return f, df
    poly = 1.0 + sum(a * r2 ** (k + 1) for k, a in enumerate(radial))
    return f * poly, df * poly + f * sum((k + 1) * a * r2 ** k for k, a in enumerate(radial))


def flat_field(cam: Camera, vignetting) -> np.ndarray:
    """The scene's [vignetting] gain of ``cam`` (H, W) float64: the flat-field image."""
    return gain(cam, vignetting.natural, tuple(vignetting.radial))


def flat_field_rig_jacobian(cam: Camera, vignetting) -> np.ndarray:
    """∂(:func:`flat_field`)/∂(``cam``'s parameters) (H·W, 23) in the rig Jacobian's columns
    (glsim.imaging.jacobian.RIG_COLUMNS): the gain moves with the rays' x_n as the intrinsics
    and distortion move them (∂g/∂r² · 2 x_n · ∂x_n/∂params); the pose does not move it; 0 where
    the pixel has no ray."""
    from glsim.imaging.jacobian import RIG_COLUMNS, ray_parameter_jacobian

    q = pixel_grid(cam).reshape(-1, 2)
    xn, ok = undistort(pixel_to_normalized(q, cam.intrinsics), cam.distortion.coeffs)
    dg = np.where(ok, _falloff(xn[:, 0] ** 2 + xn[:, 1] ** 2, vignetting.natural, tuple(vignetting.radial))[1], 0.0)
    out = np.zeros((len(q), len(RIG_COLUMNS)))
    out[:, 6:] = np.einsum("n,nl,nlp->np", 2.0 * dg, xn, ray_parameter_jacobian(cam, q, xn))
    return out


def through_flat_field(J, cam: Camera, vignetting, gain_term=None):
    """The derivative of vignetting: an image Jacobian ``J`` (W·H × n, sparse) of the image
    before it → after its gain per pixel; ``gain_term``: what the gain's own change adds (a rig
    Jacobian's diag(image)·∂gain, :func:`flat_field_rig_jacobian`)."""
    from scipy import sparse

    J = sparse.diags(flat_field(cam, vignetting).ravel()) @ J
    return J if gain_term is None else J + gain_term
