"""Stage "mesh → camera": per-element data of one camera view of one load step, in float64.

Everything is expressed relative to the rendering camera's centre (its own frame) on the CPU
in float64 before any upload, so a specimen metres from the world origin keeps its precision
in float32 shaders. Both backends consume a :class:`View`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from glsim.scene.camera import Camera, distort, normalized_to_pixel, project_camera_frame, to_camera
from glsim.errors import RenderWarning, SceneError

NEAR_MM = 1e-3  # corners closer to the camera plane than this cannot be projected
GRAZING_DEG = 85.0
GRAZING_COS = float(np.cos(np.radians(GRAZING_DEG)))
ZERO_AREA_REL = 1e-12  # element area ≤ this × the median element's: "zero area"
TINY_AREA_REL = 1e-6  # ≤ this × the median: "tiny" (still drawn, watertight)
COVER_PAD_PX = 1.0 / 8.0  # cover rectangles reach this far beyond the element's image


@dataclass(frozen=True, eq=False)
class View:
    """One camera's view of one step. Arrays are per element (M) and per corner (4).

    ``Xd``: deformed corners in the camera frame (mm). ``Xr``: undeformed corners in the
    reference camera's frame (mm). ``uv``: distorted pixel projections of ``Xd``.
    ``ref_uv``: reference-image coordinates of the corners. ``projectable``: all four
    corners in front of the camera and inside the distortion model's valid radius (the
    ``fast`` and ``q4`` modes draw only these). ``cover``: a rectangle (4 corners, px) that
    contains the element's image, which the ``exact`` mode rasterizes; ``bbox``: the pixels
    whose area meets it, [u0, v0, u1, v1] (inclusive, clipped; u1 < u0 when the element
    cannot be seen).
    """
    camera: Camera
    ref_camera: Camera
    Xd: np.ndarray
    Xr: np.ndarray
    uv: np.ndarray
    ref_uv: np.ndarray
    projectable: np.ndarray
    cover: np.ndarray
    bbox: np.ndarray
    far: float


def _cover(cam: Camera, Xd: np.ndarray, projectable: np.ndarray, behind: np.ndarray):
    """Conservative covers of each element's distorted image: a rectangle (M, 4, 2) px
    oriented along the element (the exact mode rasterizes it) and its pixel box.

    A bilinear patch lies in the convex hull of its corners, bounded by segments between
    corners; their pinhole images are straight and the distortion bends them. The six corner
    segments are sampled in normalized coordinates and distorted; the rectangle holds the
    samples, padded by twice the largest sagitta between samples. Elements that are not
    projectable but not wholly behind the camera get the whole image.
    """
    M = len(Xd)
    W, H = cam.size
    z = np.where(projectable[:, None], Xd[..., 2], 1.0)
    xn = Xd[..., :2] / z[..., None]
    t = np.linspace(0.0, 1.0, 9)[:, None]
    pairs = ((0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3))
    pts = np.concatenate([xn[:, None, i] + t[None] * (xn[:, None, j] - xn[:, None, i]) for i, j in pairs], axis=1)
    k = cam.distortion.coeffs
    uv = normalized_to_pixel(distort(pts, k), cam.intrinsics)
    seg = uv.reshape(M, len(pairs), len(t), 2)
    mid = normalized_to_pixel(distort(0.5 * (pts.reshape(seg.shape)[:, :, :-1] + pts.reshape(seg.shape)[:, :, 1:]), k),
                              cam.intrinsics)
    sag = np.linalg.norm(mid - 0.5 * (seg[:, :, :-1] + seg[:, :, 1:]), axis=-1).reshape(M, -1).max(axis=1)
    # the rasterizer snaps cover vertices to its sub-pixel grid (1/256 px on llvmpipe, 1/16 on
    # some GPUs) and rounds them to float32: pad by more than either, so every pixel centre
    # the element may own gets a fragment and the fragment stage's tie rule decides
    pad = 2.0 * sag + COVER_PAD_PX + 1e-6 * (np.abs(uv).max(axis=(1, 2)) + W + H)
    corners = uv[:, ::len(t)][:, :4]                     # the distorted corners 0, 1, 2, 3
    a = (corners[:, 1] - corners[:, 0]) + (corners[:, 2] - corners[:, 3])
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    a = np.where(norm > 0, a / np.where(norm > 0, norm, 1.0), [1.0, 0.0])
    b = np.stack([-a[:, 1], a[:, 0]], 1)
    pa = np.einsum("mnd,md->mn", uv, a)
    pb = np.einsum("mnd,md->mn", uv, b)
    lo_a, hi_a = pa.min(1) - pad, pa.max(1) + pad
    lo_b, hi_b = pb.min(1) - pad, pb.max(1) + pad
    rect = np.stack([lo_a[:, None] * a + lo_b[:, None] * b, hi_a[:, None] * a + lo_b[:, None] * b,
                     hi_a[:, None] * a + hi_b[:, None] * b, lo_a[:, None] * a + hi_b[:, None] * b], 1)
    whole = ~projectable & ~behind
    rect[whole] = [(-0.5, -0.5), (W - 0.5, -0.5), (W - 0.5, H - 0.5), (-0.5, H - 0.5)]
    box = np.empty((M, 4), dtype=np.int64)  # pixels whose area meets the rectangle (any spp)
    box[:, :2] = np.clip(np.ceil(rect.min(axis=1) - 0.5), 0, [W, H])
    box[:, 2:] = np.clip(np.floor(rect.max(axis=1) + 0.5), -1, [W - 1, H - 1])
    box[behind] = (0, 0, -1, -1)
    return rect, box


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
    cover, bbox = _cover(cam, Xd, projectable, behind)
    return View(camera=cam, ref_camera=ref_cam, Xd=Xd, Xr=Xr, uv=uv, ref_uv=ref_uv,
                projectable=projectable, cover=cover, bbox=bbox, far=max(zmax, NEAR_MM) * 1.5)


def _warn_shape(cam: Camera, Xd: np.ndarray, labels: np.ndarray | None) -> None:
    """Warn about zero-area, tiny, folded (bow-tie / inverted) and grazing elements, naming
    each element once, under its first problem in that order. Areas are relative to the
    mesh's median element."""
    n1 = np.cross(Xd[:, 1] - Xd[:, 0], Xd[:, 2] - Xd[:, 0])
    n2 = np.cross(Xd[:, 2] - Xd[:, 0], Xd[:, 3] - Xd[:, 0])
    area = 0.5 * (np.linalg.norm(n1, axis=1) + np.linalg.norm(n2, axis=1))
    positive = area[area > 0]
    median = float(np.median(positive)) if positive.size else 0.0
    zero = area <= ZERO_AREA_REL * median
    tiny = ~zero & (area <= TINY_AREA_REL * median)
    folded = ~zero & ~tiny & ((n1 * n2).sum(axis=1) < 0)
    view = Xd.mean(axis=1)  # from the camera (at the origin) to the element's centre
    normal = np.cross(Xd[:, 2] - Xd[:, 0], Xd[:, 3] - Xd[:, 1])
    cos = np.abs((normal * view).sum(1)) / np.maximum(np.linalg.norm(normal, axis=1) * np.linalg.norm(view, axis=1),
                                                        1e-300)
    grazing = ~zero & ~tiny & ~folded & (cos < GRAZING_COS)
    for bad, what in ((zero, "have zero area"),
                      (tiny, f"are tiny (area below {TINY_AREA_REL:g} of the median element's)"),
                      (folded, "are folded (inverted or bow-tie)"),
                      (grazing, f"are seen at more than {GRAZING_DEG:g}° from their normal (grazing): "
                                "the fast and q4 modes' mapping error grows there")):
        if bad.any():
            warnings.warn(f"camera {cam.name}: elements {_labels(np.flatnonzero(bad), labels)} {what}; "
                          "their pixels stay finite and consistent; check the mesh or the view",
                          RenderWarning, stacklevel=3)


def warn_dropped(cam: Camera, count: int, s: int) -> None:
    """Warn, with their number, about samples that hit the specimen but whose reference point
    lies outside the reference image (or cannot be projected into it): they are left at the
    background grey."""
    if count > 0:
        where = "pixels" if s == 1 else f"samples ({s}×{s} per pixel)"
        warnings.warn(f"camera {cam.name}: {count} {where} see the specimen but map outside the "
                      "reference image and are left at the background; enlarge the reference "
                      "image (speckle.mm_per_px or size) or check the reference camera",
                      RenderWarning, stacklevel=4)


def _labels(idx: np.ndarray, labels: np.ndarray | None, most: int = 8) -> str:
    names = (labels[idx] if labels is not None else idx).tolist()
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(map(str, names[:most])) + more
