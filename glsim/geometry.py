"""Stage "mesh → camera": per-element data of one camera view of one load step, in float64.

Everything is expressed relative to the rendering camera's centre (its own frame) on the CPU
in float64 before any upload, so a specimen metres from the world origin keeps its precision
in float32 shaders. Both backends consume a :class:`View`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from .camera import Camera, distort, normalized_to_pixel, project_camera_frame, to_camera
from .errors import RenderWarning, SceneError

NEAR_MM = 1e-3  # corners closer to the camera plane than this cannot be projected


@dataclass(frozen=True, eq=False)
class View:
    """One camera's view of one step. Arrays are per element (M) and per corner (4).

    ``Xd``: deformed corners in the camera frame (mm). ``Xr``: undeformed corners in the
    reference camera's frame (mm). ``uv``: distorted pixel projections of ``Xd``.
    ``ref_uv``: reference-image coordinates of the corners. ``projectable``: all four
    corners in front of the camera and inside the distortion model's valid radius (the
    ``fast`` and ``q4`` modes draw only these). ``bbox``: conservative pixel box
    [u0, v0, u1, v1] (inclusive, clipped) that contains the element's image in the
    ``exact`` mode; u1 < u0 when the element cannot be seen.
    """
    camera: Camera
    ref_camera: Camera
    Xd: np.ndarray
    Xr: np.ndarray
    uv: np.ndarray
    ref_uv: np.ndarray
    projectable: np.ndarray
    bbox: np.ndarray
    far: float


def _bbox_exact(cam: Camera, Xd: np.ndarray, projectable: np.ndarray, behind: np.ndarray) -> np.ndarray:
    """Pixel boxes containing each element's distorted image.

    A bilinear patch lies in the convex hull of its corners, whose pinhole image lies in the
    box of the corners' normalized coordinates; the box's boundary is sampled, distorted and
    padded by twice the largest sagitta between samples plus one pixel. Elements that are not
    projectable but not wholly behind the camera get the whole image.
    """
    M = len(Xd)
    W, H = cam.size
    z = np.where(projectable[:, None], Xd[..., 2], 1.0)
    xn = Xd[..., :2] / z[..., None]
    lo, hi = xn.min(axis=1), xn.max(axis=1)
    n = 9
    s = np.linspace(0.0, 1.0, n)
    # boundary of the normalized box: 4 edges × n samples, plus mid-points between samples
    edges = [np.stack([s, 0 * s], -1), np.stack([1 + 0 * s, s], -1),
             np.stack([s, 1 + 0 * s], -1), np.stack([0 * s, s], -1)]
    frac = np.concatenate(edges)                                  # (4n, 2)
    pts = lo[:, None, :] + frac[None] * (hi - lo)[:, None, :]      # (M, 4n, 2)
    k = cam.distortion.coeffs
    uv = normalized_to_pixel(distort(pts, k), cam.intrinsics)
    mid = normalized_to_pixel(distort(0.5 * (pts[:, :-1] + pts[:, 1:]), k), cam.intrinsics)
    sag = np.linalg.norm(mid - 0.5 * (uv[:, :-1] + uv[:, 1:]), axis=-1).max(axis=1)
    pad = 1.0 + 2.0 * sag
    box = np.empty((M, 4))
    box[:, :2] = np.floor(uv.min(axis=1) - pad[:, None])
    box[:, 2:] = np.ceil(uv.max(axis=1) + pad[:, None])
    whole = ~projectable & ~behind
    box[whole] = (0, 0, W - 1, H - 1)
    out = np.empty((M, 4), dtype=np.int64)
    out[:, 0] = np.clip(box[:, 0], 0, W)
    out[:, 1] = np.clip(box[:, 1], 0, H)
    out[:, 2] = np.clip(box[:, 2], -1, W - 1)
    out[:, 3] = np.clip(box[:, 3], -1, H - 1)
    out[behind] = (0, 0, -1, -1)
    return out


def make_view(cam: Camera, ref_cam: Camera, nodes_ref: np.ndarray, nodes_def: np.ndarray,
              quads: np.ndarray, element_labels: np.ndarray | None = None) -> View:
    """Build the :class:`View` of the deformed nodes (world, mm) seen by ``cam``.

    ``nodes_ref`` are the undeformed nodes (world, mm), projected by ``ref_cam`` to the
    reference image. Warns (naming elements) about elements that only the exact mode draws.
    """
    Xd = to_camera(nodes_def, cam)[quads]
    Xr = to_camera(nodes_ref, ref_cam)[quads]
    uv, ok = project_camera_frame(Xd, cam)
    ref_uv, ref_ok = project_camera_frame(Xr, ref_cam)
    if not ref_ok.all():
        bad = np.flatnonzero(~ref_ok.all(axis=1))
        raise SceneError("speckle.camera", f"the reference camera cannot see elements "
                         f"{_labels(bad, element_labels)}", "place it so the whole undeformed specimen "
                         "is in front of it and inside its distortion model's valid radius")
    _warn_shape(cam, Xd, element_labels)
    projectable = ok.all(axis=1)
    behind = (Xd[..., 2] <= NEAR_MM).all(axis=1)
    if (~projectable & ~behind).any():
        bad = np.flatnonzero(~projectable & ~behind)
        warnings.warn(f"camera {cam.name}: elements {_labels(bad, element_labels)} cross the camera "
                      "plane or leave the distortion model's valid radius; the fast and q4 modes "
                      "drop them, the exact mode intersects them per pixel", RenderWarning, stacklevel=3)
    zmax = float(Xd[..., 2].max()) if len(Xd) else 1.0
    return View(camera=cam, ref_camera=ref_cam, Xd=Xd, Xr=Xr, uv=uv, ref_uv=ref_uv,
                projectable=projectable, bbox=_bbox_exact(cam, Xd, projectable, behind),
                far=max(zmax, NEAR_MM) * 1.5)


def _warn_shape(cam: Camera, Xd: np.ndarray, labels: np.ndarray | None) -> None:
    """Warn about zero-area and folded (bow-tie / inverted) elements, naming them."""
    n1 = np.cross(Xd[:, 1] - Xd[:, 0], Xd[:, 2] - Xd[:, 0])
    n2 = np.cross(Xd[:, 2] - Xd[:, 0], Xd[:, 3] - Xd[:, 0])
    area = 0.5 * (np.linalg.norm(n1, axis=1) + np.linalg.norm(n2, axis=1))
    size = np.ptp(Xd.reshape(-1, 3), axis=0).max() if len(Xd) else 1.0
    zero = area <= 1e-12 * size * size
    folded = ~zero & ((n1 * n2).sum(axis=1) < 0)
    for bad, what in ((zero, "have zero area"), (folded, "are folded (inverted or bow-tie)")):
        if bad.any():
            warnings.warn(f"camera {cam.name}: elements {_labels(np.flatnonzero(bad), labels)} {what}; "
                          "pixels that map into them stay consistent but check the mesh",
                          RenderWarning, stacklevel=3)


def _labels(idx: np.ndarray, labels: np.ndarray | None, most: int = 8) -> str:
    names = (labels[idx] if labels is not None else idx).tolist()
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(map(str, names[:most])) + more
