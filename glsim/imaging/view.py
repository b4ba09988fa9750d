"""Stage "mesh → camera": per-element data of one camera view of one load step, in float64.

Everything is expressed relative to the rendering camera's centre (its own frame) on the CPU
in float64, so a specimen metres from the world origin keeps its precision. The CPU oracle
consumes a full :class:`View` (:func:`make_view`, numpy, chunked so that 10⁶ elements fit in
memory); the GL backend computes the same per-element data on the GPU from the mesh uploaded
once (``shaders/view.glsl``, the GLSL twin of :func:`cover_rectangles`) and takes a
:class:`glsim.imaging.geometry.ViewSpec` instead.
"""
from __future__ import annotations

import functools
import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from glsim.scene.camera import (Camera, distort, normalized_to_pixel, pixel_to_normalized, project,
                                project_camera_frame, to_camera, undistort)
from glsim.errors import RenderWarning, SceneError

NEAR_MM = 1e-3  # corners closer to the camera plane than this cannot be projected
GRAZING_DEG = 85.0
GRAZING_COS = float(np.cos(np.radians(GRAZING_DEG)))
ZERO_AREA_REL = 1e-12  # element area ≤ this × the median element's: "zero area"
TINY_AREA_REL = 1e-6  # ≤ this × the median: "tiny" (still drawn, watertight)
COVER_PAD_PX = 1.0 / 8.0  # cover rectangles reach this far beyond the element's image
TIGHT_PAD_PX = 1.0 / 1024.0  # GL candidate lists: the tight rectangles' pad (float32 rounding only)
COVER_SEGMENTS = ((0, 1), (1, 2), (2, 3), (3, 0), (0, 2), (1, 3))  # the corners' convex hull's edges
COVER_FINE_INTERVALS = 8  # intervals per segment where one segment's sagitta is not negligible
COVER_COARSE_SAG_PX = 1.0 / 64.0  # largest whole-segment sagitta (px) drawn from corners and midpoints
COVER_BOUNDARY_INTERVALS = 8  # intervals per side of an unprojectable element's footprint box
CHUNK_ELEMENTS = 1 << 15  # elements whose covers are computed at once (bounds memory)


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

    def subset(self, elements: np.ndarray) -> "View":
        """The view of ``elements`` only (indices into this view's elements)."""
        return View(camera=self.camera, ref_camera=self.ref_camera, Xd=self.Xd[elements], Xr=self.Xr[elements],
                    uv=self.uv[elements], ref_uv=self.ref_uv[elements], projectable=self.projectable[elements],
                    cover=self.cover[elements], bbox=self.bbox[elements], far=self.far)

    def corner_depths(self) -> np.ndarray:
        """Camera-frame Z (mm) of every element corner."""
        return self.Xd[..., 2]


# ---- conservative covers ---------------------------------------------------------------------
@functools.lru_cache(maxsize=64)
def _ray_radius(size: tuple, intr: tuple, k: tuple) -> float:
    k = np.asarray(k)
    rv = _valid_radius(k)
    W, H = size
    n = max(W, H) // 2 + 2
    u = np.linspace(-0.5, W - 0.5, n)
    v = np.linspace(-0.5, H - 0.5, n)
    border = np.concatenate([np.stack([u, np.full(n, -0.5)], 1), np.stack([u, np.full(n, H - 0.5)], 1),
                             np.stack([np.full(n, -0.5), v], 1), np.stack([np.full(n, W - 0.5), v], 1)])
    xn, ok = undistort(pixel_to_normalized(border, np.asarray(intr)), k)
    if not ok.all():      # some pixels have no ray: they lie beyond the valid radius
        return rv
    return min(rv, 1.01 * float(np.linalg.norm(xn, axis=1).max()))


def _valid_radius(k) -> float:
    from glsim.scene.camera import valid_radius
    return valid_radius(k)


def ray_radius(cam: Camera) -> float:
    """An upper bound of |xn| (normalized undistorted radius) over the rays of every sample of
    ``cam``'s image: the valid radius, or 1 % beyond the largest ray of the image border where
    that is smaller (the undistorted radius grows with the distorted one). May be inf."""
    return _ray_radius(tuple(cam.size), cam.intrinsic_values, cam.distortion.values)


def _oriented_rect(uv: np.ndarray, a: np.ndarray, pad: np.ndarray) -> np.ndarray:
    """Rectangles (m, 4, 2) along unit axes a (m, 2) holding the points uv (m, n, 2), padded."""
    b = np.stack([-a[:, 1], a[:, 0]], 1)
    pa = np.einsum("mnd,md->mn", uv, a)
    pb = np.einsum("mnd,md->mn", uv, b)
    lo_a, hi_a = pa.min(1) - pad, pa.max(1) + pad
    lo_b, hi_b = pb.min(1) - pad, pb.max(1) + pad
    return np.stack([lo_a[:, None] * a + lo_b[:, None] * b, hi_a[:, None] * a + lo_b[:, None] * b,
                     hi_a[:, None] * a + hi_b[:, None] * b, lo_a[:, None] * a + hi_b[:, None] * b], 1)


def _pad(cam: Camera, uv: np.ndarray, sag: np.ndarray) -> np.ndarray:
    # the rasterizer snaps cover vertices to its sub-pixel grid (1/256 px on llvmpipe, 1/16 on
    # some GPUs) and rounds them to float32: pad by more than either, so every pixel centre
    # the element may own gets a fragment and the fragment stage's tie rule decides
    W, H = cam.size
    return 2.0 * sag + COVER_PAD_PX + 1e-6 * (np.abs(uv).max(axis=(1, 2)) + W + H)


def _projectable_covers(cam: Camera, Xd: np.ndarray) -> np.ndarray:
    """Covers of elements whose corners all project: the convex hull of the corners is bounded
    by the six corner segments, whose pinhole images are straight and which the distortion
    bends. Each segment is distorted at its ends and midpoint; where no midpoint strays more
    than COVER_COARSE_SAG_PX from its chord, the rectangle holds corners and midpoints padded
    by twice the largest such sagitta, else the segments are sampled at COVER_FINE_INTERVALS
    intervals and padded by twice the largest sagitta between samples."""
    k, intr = cam.distortion.coeffs, cam.intrinsics
    M = len(Xd)
    xn = Xd[..., :2] / Xd[..., 2:3]
    i, j = np.array(COVER_SEGMENTS).T
    uvc = normalized_to_pixel(distort(xn, k), intr)
    uvm = normalized_to_pixel(distort(0.5 * (xn[:, i] + xn[:, j]), k), intr)
    sag = np.linalg.norm(uvm - 0.5 * (uvc[:, i] + uvc[:, j]), axis=-1).max(axis=1)
    a = (uvc[:, 1] - uvc[:, 0]) + (uvc[:, 2] - uvc[:, 3])
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    a = np.where(norm > 0, a / np.where(norm > 0, norm, 1.0), [1.0, 0.0])
    pts = np.concatenate([uvc, uvm], axis=1)
    rect = np.empty((M, 4, 2))
    coarse = sag <= COVER_COARSE_SAG_PX
    rect[coarse] = _oriented_rect(pts[coarse], a[coarse], _pad(cam, pts[coarse], sag[coarse]))
    fine = np.flatnonzero(~coarse)
    if fine.size:
        n = COVER_FINE_INTERVALS
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        x = xn[fine]
        seg = np.stack([x[:, None, a_] + t[None] * (x[:, None, b_] - x[:, None, a_]) for a_, b_ in COVER_SEGMENTS], 1)
        uvs = normalized_to_pixel(distort(seg, k), intr)                           # (f, 6, n + 1, 2)
        mids = normalized_to_pixel(distort(0.5 * (seg[:, :, :-1] + seg[:, :, 1:]), k), intr)
        sag_f = np.linalg.norm(mids - 0.5 * (uvs[:, :, :-1] + uvs[:, :, 1:]), axis=-1).reshape(len(fine), -1).max(1)
        uvs = uvs.reshape(len(fine), -1, 2)
        rect[fine] = _oriented_rect(uvs, a[fine], _pad(cam, uvs, sag_f))
    return rect


def footprint_box(Xd: np.ndarray, radius: float):
    """Bounding box [x0, y0, x1, y1] (m, 4) in normalized undistorted coordinates of the rays
    (x, y, 1) that can meet an element which does not project (a corner behind the camera
    or beyond the valid radius), clipped to |x|, |y| ≤ ``radius`` (no sample's ray lies
    beyond it): the element lies in the convex hull of its corners, whose rays are the
    projections of the corners in front of the camera plus, for each corner i in front and
    j behind, the direction z_i·P_j − z_j·P_i of their segment's crossing of the plane (a
    point at infinity)."""
    z = Xd[..., 2]
    front = z > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        p = Xd[..., :2] / np.where(front, z, 1.0)[..., None]
    lo = np.where(front[..., None], p, np.inf).min(axis=1)
    hi = np.where(front[..., None], p, -np.inf).max(axis=1)
    for i in range(4):
        for j in range(4):
            cross = front[:, i] & ~front[:, j]
            d = z[:, i, None] * Xd[:, j, :2] - z[:, j, None] * Xd[:, i, :2]
            zero = cross & (d == 0).all(axis=1)
            lo = np.where((cross[:, None] & (d < 0)) | zero[:, None], -np.inf, lo)
            hi = np.where((cross[:, None] & (d > 0)) | zero[:, None], np.inf, hi)
    lo, hi = np.maximum(lo, -radius), np.minimum(hi, radius)
    return np.concatenate([lo, hi], axis=1)


def _unprojectable_covers(cam: Camera, Xd: np.ndarray, radius: float):
    """Covers (m, 4, 2) and visibility (m,) of elements that do not project: the boundary of
    their footprint box (:func:`footprint_box`), each sample pulled radially onto the disc of
    ``radius`` (which then also covers the disc's boundary inside the box), distorted, and
    padded by twice the largest sagitta between samples."""
    k, intr = cam.distortion.coeffs, cam.intrinsics
    W, H = cam.size
    m = len(Xd)
    if not np.isfinite(radius):  # nothing bounds the rays: the whole image
        rect = np.broadcast_to(np.array([(-0.5, -0.5), (W - 0.5, -0.5), (W - 0.5, H - 0.5), (-0.5, H - 0.5)]),
                               (m, 4, 2)).copy()
        return rect, np.ones(m, bool)
    box = footprint_box(Xd, radius)
    seen = (box[:, 0] <= box[:, 2]) & (box[:, 1] <= box[:, 3])
    box = np.where(seen[:, None], box, 0.0)
    corners = box[:, [[0, 1], [2, 1], [2, 3], [0, 3]]]                                     # (m, 4, 2)
    n = COVER_BOUNDARY_INTERVALS
    t = (np.arange(2 * n) / (2 * n))[:, None]
    sides = np.concatenate([corners[:, s, None] + t[None] * (corners[:, (s + 1) % 4, None] - corners[:, s, None])
                            for s in range(4)], axis=1)                                      # (m, 8n, 2)
    r = np.linalg.norm(sides, axis=-1, keepdims=True)
    sides = sides * np.minimum(1.0, radius / np.where(r > 0, r, 1.0))
    uv = normalized_to_pixel(distort(sides, k), intr)
    pts, mids = uv[:, 0::2], uv[:, 1::2]
    sag = np.linalg.norm(mids - 0.5 * (pts + np.roll(pts, -1, axis=1)), axis=-1).max(axis=1)
    rect = _oriented_rect(uv, np.broadcast_to([1.0, 0.0], (m, 2)), _pad(cam, uv, sag))
    return rect, seen


def cover_rectangles(cam: Camera, Xd: np.ndarray, projectable: np.ndarray, behind: np.ndarray):
    """Conservative covers of each element's distorted image: a rectangle (M, 4, 2) px (the
    exact mode rasterizes it; ``shaders/view.glsl`` computes the same on the GPU) and its
    pixel box [u0, v0, u1, v1] (M, 4), empty (u1 < u0) where the element cannot be seen.

    Projectable elements: :func:`_projectable_covers`. Elements that do not project but are
    not wholly behind the camera: :func:`_unprojectable_covers`, bounded by the rays the
    image's samples can have (:func:`ray_radius`), so that an element beyond the valid radius
    or crossing the camera plane is not tested against the whole image. Computed in chunks
    of CHUNK_ELEMENTS elements.
    """
    M = len(Xd)
    W, H = cam.size
    rect = np.zeros((M, 4, 2))
    seen = ~behind.copy()
    radius = ray_radius(cam)
    for s in range(0, M, CHUNK_ELEMENTS):
        sl = slice(s, min(M, s + CHUNK_ELEMENTS))
        p = np.flatnonzero(projectable[sl]) + s
        if p.size:
            rect[p] = _projectable_covers(cam, Xd[p])
        u = np.flatnonzero(~projectable[sl] & ~behind[sl]) + s
        if u.size:
            rect[u], seen[u] = _unprojectable_covers(cam, Xd[u], radius)
    box = np.empty((M, 4), dtype=np.int64)  # pixels whose area meets the rectangle (any spp)
    box[:, :2] = np.clip(np.ceil(rect.min(axis=1) - 0.5), 0, [W, H])
    box[:, 2:] = np.clip(np.floor(rect.max(axis=1) + 0.5), -1, [W - 1, H - 1])
    box[~seen] = (0, 0, -1, -1)
    return rect, box


# ---- the view --------------------------------------------------------------------------------
def check_reference(ref_ok: np.ndarray, element_labels: np.ndarray | None) -> None:
    """Raise if the reference camera cannot project every corner (ref_ok: (M, 4) or (M,))."""
    ok = ref_ok.all(axis=1) if ref_ok.ndim == 2 else ref_ok
    if not ok.all():
        bad = np.flatnonzero(~ok)
        raise SceneError("speckle.camera", f"the reference camera cannot see elements "
                         f"{_labels(bad, element_labels)}", "place it so the whole undeformed specimen "
                         "is in front of it and inside its distortion model's valid radius")


def make_view(cam: Camera, ref_cam: Camera, nodes_ref: np.ndarray, nodes_def: np.ndarray,
              quads: np.ndarray, element_labels: np.ndarray | None = None, warn: bool = True) -> View:
    """Build the :class:`View` of the deformed nodes (world, mm) seen by ``cam``.

    ``nodes_ref`` are the undeformed nodes (world, mm), projected by ``ref_cam`` to the
    reference image. Warns (naming elements, :func:`warn_problems`) about degenerate elements
    and elements that only the exact mode draws, unless ``warn`` is False.
    """
    Xd = to_camera(nodes_def, cam)[quads]
    Xr = to_camera(nodes_ref, ref_cam)[quads]
    uv, ok = project_camera_frame(Xd, cam)
    ref_uv, ref_ok = project_camera_frame(Xr, ref_cam)
    check_reference(ref_ok, element_labels)
    projectable = ok.all(axis=1)
    behind = (Xd[..., 2] <= NEAR_MM).all(axis=1)
    if warn:
        shape = shape_problems(Xd)
        problems = {**shape, "grazing": grazing(Xd) & ~shape["excluded"], "unprojectable": ~projectable & ~behind}
        warn_problems(cam, problems, element_labels)
    zmax = float(Xd[..., 2].max()) if len(Xd) else 1.0
    cover, bbox = cover_rectangles(cam, Xd, projectable, behind)
    return View(camera=cam, ref_camera=ref_cam, Xd=Xd, Xr=Xr, uv=uv, ref_uv=ref_uv,
                projectable=projectable, cover=cover, bbox=bbox, far=max(zmax, NEAR_MM) * 1.5)


# ---- warnings ---------------------------------------------------------------------------------
def element_areas(X: np.ndarray):
    """Areas (M,) of the two triangles (0, 1, 2) + (0, 2, 3) of the elements with corners X
    (M, 4, 3) and whether their normals oppose (a bow-tie or inverted element); invariant under
    rigid motions, so once per load step (:func:`corner_areas`)."""
    X = np.asarray(X, np.float64)
    return corner_areas(X[:, :, 0].T, X[:, :, 1].T, X[:, :, 2].T)


def mesh_element_areas(nodes: np.ndarray, quads: np.ndarray, chunk: int = CHUNK_ELEMENTS):
    """:func:`element_areas` of ``nodes[quads]`` (nodes (N, 3), quads (M, 4)) bit for bit,
    gathered one coordinate at a time (numpy's gather and arithmetic on rows of 3 loop over 3
    at a time) and ``chunk`` elements at a time (bounds memory)."""
    cols = [np.ascontiguousarray(nodes[:, k], np.float64) for k in range(3)]
    M = len(quads)
    area, opposed = np.empty(M), np.empty(M, bool)
    for s in range(0, M, chunk):
        corners = np.ascontiguousarray(quads[s:s + chunk].T)   # (corner, element)
        area[s:s + chunk], opposed[s:s + chunk] = corner_areas(*(c[corners] for c in cols))
    return area, opposed


def corner_areas(x: np.ndarray, y: np.ndarray, z: np.ndarray):
    """:func:`element_areas` from the corners' coordinates, each (4, M) (corner, element):
    written out per component on (M,) rows — numpy's cross, norm and sum over the last axis of
    (M, 3) arrays loop over 3 at a time — in their order of operations, so the values are
    theirs bit for bit."""
    ax, ay, az = x[1] - x[0], y[1] - y[0], z[1] - z[0]
    bx, by, bz = x[2] - x[0], y[2] - y[0], z[2] - z[0]
    cx, cy, cz = x[3] - x[0], y[3] - y[0], z[3] - z[0]
    n1x, n1y, n1z = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx   # (1 − 0) × (2 − 0)
    n2x, n2y, n2z = by * cz - bz * cy, bz * cx - bx * cz, bx * cy - by * cx   # (2 − 0) × (3 − 0)
    area = 0.5 * (np.sqrt(n1x * n1x + n1y * n1y + n1z * n1z) + np.sqrt(n2x * n2x + n2y * n2y + n2z * n2z))
    return area, (n1x * n2x + n1y * n2y + n1z * n2z) < 0


def shape_problems(X: np.ndarray, chunk: int = CHUNK_ELEMENTS) -> dict[str, np.ndarray]:
    """Zero-area, tiny and folded elements (:func:`classify_shapes`) from the corners X
    (M, 4, 3) in any Cartesian frame."""
    M = len(X)
    area, opposed = np.empty(M), np.empty(M, bool)
    for s in range(0, M, chunk):
        area[s:s + chunk], opposed[s:s + chunk] = element_areas(X[s:s + chunk])
    return classify_shapes(area, opposed)


def classify_shapes(area: np.ndarray, opposed: np.ndarray) -> dict[str, np.ndarray]:
    """Zero-area, tiny and folded elements (bool (M,) each, exclusive in that order), relative
    to the mesh's median element area, from :func:`element_areas`' values; ``excluded`` is
    their union (such elements are not also named as grazing)."""
    median = _median(area[area > 0])
    zero = area <= ZERO_AREA_REL * median
    tiny = ~zero & (area <= TINY_AREA_REL * median)
    folded = ~zero & ~tiny & opposed
    return {"zero": zero, "tiny": tiny, "folded": folded, "excluded": zero | tiny | folded}


def _median(a: np.ndarray) -> float:
    """np.median of ``a`` (1-D, no NaN) bit for bit — the mean of the two middle values for an
    even count — by one partition, without np.median's generic reduction; 0 if empty."""
    n = a.size
    if n == 0:
        return 0.0
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    p = np.partition(a, (k - 1, k))
    return float((p[k - 1] + p[k]) / 2)


def grazing(Xd: np.ndarray, chunk: int = CHUNK_ELEMENTS) -> np.ndarray:
    """Elements seen at more than GRAZING_DEG from their normal (bool (M,)), from the corners
    in the camera frame (the camera at the origin)."""
    out = np.empty(len(Xd), bool)
    for s in range(0, len(Xd), chunk):
        X = Xd[s:s + chunk]
        view = X.mean(axis=1)  # from the camera (at the origin) to the element's centre
        normal = np.cross(X[:, 2] - X[:, 0], X[:, 3] - X[:, 1])
        cos = np.abs((normal * view).sum(1)) / np.maximum(np.linalg.norm(normal, axis=1) * np.linalg.norm(view, axis=1),
                                                            1e-300)
        out[s:s + chunk] = cos < GRAZING_COS
    return out


def warn_problems(cam: Camera, problems: dict, labels: np.ndarray | None, stacklevel: int = 4) -> None:
    """The element warnings of one view: zero area, tiny, folded, grazing (each element named
    once, under its first problem) and elements that cross the camera plane or leave the
    valid radius. ``problems`` maps those names to bool masks (M,) or sorted index arrays."""
    def idx(a):
        a = np.asarray(a)
        return np.flatnonzero(a) if a.dtype == bool else a

    for key, what in (("zero", "have zero area"),
                      ("tiny", f"are tiny (area below {TINY_AREA_REL:g} of the median element's)"),
                      ("folded", "are folded (inverted or bow-tie)"),
                      ("grazing", f"are seen at more than {GRAZING_DEG:g}° from their normal (grazing): "
                                  "the fast and q4 modes' mapping error grows there")):
        bad = idx(problems.get(key, ()))
        if bad.size:
            warnings.warn(f"camera {cam.name}: elements {_labels(bad, labels)} {what}; "
                          "their pixels stay finite and consistent; check the mesh or the view",
                          RenderWarning, stacklevel=stacklevel)
    bad = idx(problems.get("unprojectable", ()))
    if bad.size:
        warnings.warn(f"camera {cam.name}: elements {_labels(bad, labels)} cross the camera "
                      "plane or leave the distortion model's valid radius; the fast and q4 modes "
                      "drop them, the exact mode intersects them per pixel", RenderWarning, stacklevel=stacklevel)


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


def coverage(cam: Camera, deformed: np.ndarray, quads: np.ndarray, samples: int = 4) -> np.ndarray:
    """(H, W) bool: pixels inside the projected deformed elements (``samples`` points per edge, so
    lens distortion bends the edges as in the image; elements that cannot be projected whole are
    left out): the specimen's pixels, without rendering."""
    import cv2

    W, H = cam.size
    mask = np.zeros((H, W), np.uint8)
    t = np.linspace(0.0, 1.0, samples + 1)[:-1]
    corners = deformed[quads]                                    # (M, 4, 3)
    nxt = np.roll(corners, -1, axis=1)
    P = corners[:, :, None] * (1 - t[None, None, :, None]) + nxt[:, :, None] * t[None, None, :, None]
    uv, ok = project(P.reshape(-1, 3), cam)
    uv = uv.reshape(len(quads), -1, 2)
    ok = ok.reshape(len(quads), -1).all(axis=1)
    uv = np.clip(uv, -1e7, 1e7)                                  # cv2's fixed point (shift 4) stays in int32
    polys = [np.rint(p * 16).astype(np.int32) for p, good in zip(uv, ok) if good]
    if polys:
        cv2.fillPoly(mask, polys, 1, lineType=cv2.LINE_8, shift=4)
    return mask.astype(bool)


def extent(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The per-coordinate minimum and maximum of points (N, d), column by column: numpy's
    reduction over axis 0 of a narrow array runs d at a time, ~20× slower (exact either way)."""
    cols = [points[:, k] for k in range(points.shape[1])]
    return np.array(list(map(np.minimum.reduce, cols))), np.array(list(map(np.maximum.reduce, cols)))


_BOX_CORNERS = np.array(list(itertools.product((0, 1), repeat=3)))   # a box's 8 corners: lo (0) or hi (1) per axis
_XYZ = np.arange(3)


def warn_unseen(cam: Camera, nodes: np.ndarray, quads: np.ndarray, stacklevel: int = 3, box=None) -> bool:
    """Warn (RenderWarning) and return False when ``cam`` sees none of the specimen (nodes in
    world mm), saying why: behind it, or outside its field of view. Decided from the nodes' bounding box (8 corners, no
    per-element work) where that suffices — all behind the camera, or all in front with their
    rays (x/z, y/z; a box's rays lie in their rectangle) farther from the axis than any ray of the
    image (:func:`ray_radius`) — else from :func:`coverage`. A box that may be seen is not
    looked at more closely. ``box``: the nodes' :func:`extent`, if known."""
    lo, hi = extent(nodes) if box is None else box
    box = to_camera(np.array((lo, hi))[_BOX_CORNERS, _XYZ], cam)   # the box's 8 corners
    z = box[:, 2]
    if np.maximum.reduce(z) <= 0:
        why = "the specimen lies behind it"
    elif np.minimum.reduce(z) > 0:
        xn = box[:, :2] / z[:, None]
        gap = np.maximum(np.maximum(np.minimum.reduce(xn), -np.maximum.reduce(xn)), 0.0)   # per axis: the rectangle's distance from the axis
        if not np.hypot(*gap) > ray_radius(cam):
            return True
        why = "the specimen lies outside its field of view"
    elif coverage(cam, nodes, quads).any():
        return True
    else:
        why = "the specimen lies behind it or outside its field of view"
    warnings.warn(f"camera {cam.name}: sees none of the specimen ({why}), so its image is background only; "
                  "check its pose (stereo angles, look_at) and focal length", RenderWarning, stacklevel=stacklevel)
    return False


def _labels(idx: np.ndarray, labels: np.ndarray | None, most: int = 8) -> str:
    """The first ``most`` FE labels of elements ``idx``, each once (the faces of one solid
    element, and the pieces of one quadratic element, share its label)."""
    names = np.asarray(labels)[idx] if labels is not None else np.asarray(idx)
    _, first = np.unique(names, return_index=True)
    names = names[np.sort(first)].tolist()
    more = f" and {len(names) - most} more" if len(names) > most else ""
    return ", ".join(map(str, names[:most])) + more
