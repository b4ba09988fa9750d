"""Stage "raster → truth": the local coordinates (ξ, η) that the truth maps are evaluated at,
in float64, and the same for both backends.

- ``exact`` and ``q4``: the (ξ, η) that coloured the sample. GL builds with float64 shaders
  write them as float32 hi + lo pairs (float64 already); others read them back as float32:
  :func:`polish_exact` / :func:`polish_q4` take two float64 Newton steps from there (the
  quadratic convergence takes a 1e-7 start to rounding level), so GL's truth is float64 too.
- ``fast``: the pixel is coloured by the reference point ``ref_uv`` interpolated linearly over
  a triangle; the material point it shows is the one the reference camera sees at ``ref_uv``.
  :func:`fast_local_coords` intersects that reference ray with the undeformed element, so
  ``X_undeformed`` / ``X_deformed`` describe the image also on triangles (collapsed quads) and
  folded elements, where the triangle's own (ξ, η) interpolation does not.
"""
from __future__ import annotations

import numpy as np

from glsim.scene import bilinear as bl
from glsim.scene.camera import pixel_to_normalized, undistort
from glsim.imaging.view import View


def newton_from(p, q, xi, eta, steps: int = 2, tol: float = 0.0):
    """Gauss–Newton on the 2-D inverse bilinear problem p (N, 4, 2) → q (N, 2) from (ξ, η),
    relative to corner 0 (as :func:`glsim.scene.bilinear.invert_newton`); at most ``steps``
    steps, each clipped to ±4, stopping per sample once |Δ| ≤ tol."""
    o = p[:, :1, :]
    p, q = p - o, q - o[:, 0, :]
    xi, eta = np.array(xi, dtype=np.float64), np.array(eta, dtype=np.float64)
    active = np.ones(len(xi), dtype=bool)
    for _ in range(steps):
        dxi, deta, _ = bl.newton_step(p[active], xi[active], eta[active], q[active])
        dxi, deta = np.clip(dxi, -4, 4), np.clip(deta, -4, 4)
        xi[active] += dxi
        eta[active] += deta
        still = np.maximum(np.abs(dxi), np.abs(deta)) > tol
        active[np.flatnonzero(active)[~still]] = False
        if not active.any():
            break
    return xi, eta


def polish_exact(view: View, e, xn, xi, eta, steps: int = 2):
    """(ξ, η) of the rays (xn, 1) on the deformed patches ``view.Xd[e]``, from a float32 start."""
    P = view.Xd[e]
    p2 = P[..., :2] - xn[:, None, :] * P[..., 2:3]
    return newton_from(p2, np.zeros((len(e), 2)), xi, eta, steps)


def polish_q4(view: View, e, q, xi, eta, steps: int = 2):
    """(ξ, η) of pixel points q in the projected elements ``view.uv[e]``, from a float32 start."""
    return newton_from(view.uv[e], q, xi, eta, steps)


def fast_local_coords(view: View, e, ref_uv, xi0, eta0):
    """(ξ, η) on the undeformed element ``view.Xr[e]`` of the material point the reference
    camera sees at ``ref_uv`` (the point that coloured a fast-mode sample), by Newton from the
    triangle's interpolated (ξ0, η0). Where the reference ray cannot be formed the start is
    kept."""
    ref = view.ref_camera
    xn, ok = undistort(pixel_to_normalized(ref_uv, ref.intrinsics), ref.distortion.coeffs)
    P = view.Xr[e]
    p2 = P[..., :2] - xn[:, None, :] * P[..., 2:3]
    xi, eta = newton_from(p2, np.zeros((len(e), 2)), xi0, eta0, steps=30, tol=1e-14)
    good = ok & np.isfinite(xi) & np.isfinite(eta)
    return np.where(good, xi, xi0), np.where(good, eta, eta0)


def polish(view: View, mode: str, raster: dict, xn=None) -> dict:
    """``raster`` (flat arrays over H·W of ``view``'s camera) with float64 (ξ, η) wherever a
    sample hit an element: :func:`polish_exact` on the pixel's ray (``xn`` (H·W, 2), the rays
    the backend used, else made here), :func:`polish_q4` at the pixel centre, or
    :func:`fast_local_coords`. The one truth-polishing step of both backends."""
    hit = np.flatnonzero(raster["element"] >= 0)
    if not hit.size:
        return raster
    W, _ = view.camera.size
    e, xi, eta = raster["element"][hit], raster["xi"][hit], raster["eta"][hit]
    q = np.column_stack([hit % W, hit // W]).astype(np.float64)
    if mode == "exact":
        cam = view.camera
        rays = undistort(pixel_to_normalized(q, cam.intrinsics), cam.distortion.coeffs)[0] if xn is None else xn[hit]
        xi, eta = polish_exact(view, e, rays, xi, eta)
    elif mode == "q4":
        xi, eta = polish_q4(view, e, q, xi, eta)
    else:
        xi, eta = fast_local_coords(view, e, raster["ref_uv"][hit], xi, eta)
    out = dict(raster, xi=raster["xi"].copy(), eta=raster["eta"].copy())
    out["xi"][hit], out["eta"][hit] = xi, eta
    return out

