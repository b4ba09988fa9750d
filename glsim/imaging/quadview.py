"""Stage "mesh → camera" for quadratic elements: per-patch data of one camera view of one load
step, in float64, for the CPU oracle's ``exact`` and ``q4`` modes (the ``fast`` mode draws the
linear pieces of :func:`glsim.scene.quadratic.linearize` through the ordinary
:class:`~glsim.imaging.view.View`).

Every element is a 9-node biquadratic patch (:mod:`glsim.scene.quadratic`). Its pixel box
comes from the patch evaluated on a QUAD_BOX_GRID × QUAD_BOX_GRID grid of (ξ, η), projected and
padded by QUAD_BOX_PAD_PX (which bounds the quadratic sag between grid points for elements
up to about a hundred pixels across; larger ones get a proportionally larger pad).
"""
from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from glsim.errors import RenderWarning
from glsim.limits import keep
from glsim.scene import quadratic as qd
from glsim.scene.camera import Camera, pixel_to_normalized, project_camera_frame, to_camera, undistort
from glsim.imaging.geometry import VIEWS_KEPT
from glsim.imaging.view import NEAR_MM, _labels, check_reference, make_view

_CACHES = itertools.count()   # a patch cache's serial: the GPU's uploads are keyed by it and the state
QUAD_BOX_GRID = 9
QUAD_BOX_PAD_PX = 2.0


@dataclass(frozen=True, eq=False)
class QuadView:
    """One camera's view of one step of a quadratic mesh, per element (M) and patch node (9).

    ``Pd``: deformed patch control points in the camera frame (mm); ``Pr``: undeformed ones in
    the reference camera's frame; ``uv``: distorted pixel projections of ``Pd``; ``ref_uv``:
    reference-image projections of ``Pr``; ``bbox``: inclusive pixel boxes [u0, v0, u1, v1],
    empty (u1 < u0) for an element that cannot be drawn; ``pieces``: the linear pieces per
    side whose corner normals the lighting interpolates (0: none given)."""
    camera: Camera
    ref_camera: Camera
    Pd: np.ndarray
    Pr: np.ndarray
    uv: np.ndarray
    ref_uv: np.ndarray
    bbox: np.ndarray
    pieces: int = 0


def make_quad_view(cam: Camera, ref_cam: Camera, nodes_ref: np.ndarray, nodes_def: np.ndarray, patches: np.ndarray,
                   labels: np.ndarray | None = None, warn: bool = True, pieces=None, pieces_def=None,
                   mode: str = "exact") -> QuadView:
    """The :class:`QuadView` of the deformed nodes (world, mm) seen by ``cam``; warns (naming
    elements) about folded patches and patches that do not wholly project.

    Pixel boxes: with ``pieces`` (the mesh's :class:`~glsim.scene.quadratic.Pieces`) and
    ``pieces_def`` (their nodes at this step), the union
    of the pieces' exact-mode covers (:func:`glsim.imaging.view.cover_rectangles`, which also
    bound pieces crossing the camera plane) grown by twice the pieces' chord error in px
    (:func:`chord_error_bound`), as the GL path draws them; without, the patch on a
    QUAD_BOX_GRID² grid, projected and padded. ``mode`` q4 draws only patches whose 9 nodes
    all project (as GL); exact also the others (rays need no projection)."""
    Pd = qd.patch_points(patches, to_camera(nodes_def, cam))
    Pr = qd.patch_points(patches, to_camera(nodes_ref, ref_cam))
    uv, node_ok = project_camera_frame(Pd, cam)
    projectable = node_ok.all(axis=1)
    ref_uv, ref_ok = project_camera_frame(Pr, ref_cam)
    check_reference(ref_ok, labels)
    W, H = cam.size
    M = len(Pd)
    if pieces is not None:
        pv = make_view(cam, ref_cam, pieces.mesh.nodes, pieces_def, pieces.mesh.quads, warn=False)
        box = pv.bbox.reshape(M, -1, 4)
        empty = (box[..., 2] < box[..., 0]) | (box[..., 3] < box[..., 1])
        z_near = max(float(Pd[..., 2].min()), NEAR_MM)
        chord_px = chord_error_bound(Pd, pieces.n) * float(cam.intrinsics[:2].max()) / z_near
        if mode == "q4":
            chord_px = max(chord_px, q4_image_bound(Pd, cam, pieces.n))
        pad = int(np.ceil(2 * 1.5 * chord_px)) + 1
        big = np.iinfo(np.int64).max // 4
        lo = np.where(empty[..., None], big, box[..., :2]).min(axis=1) - pad
        hi = np.where(empty[..., None], -big, box[..., 2:]).max(axis=1) + pad
        bbox = np.concatenate([np.clip(lo, 0, [W, H]), np.clip(hi, -1, [W - 1, H - 1])], axis=1)
        bbox[empty.all(axis=1)] = (0, 0, -1, -1)
        drawable = ~empty.all(axis=1)
    else:
        t = np.linspace(-1, 1, QUAD_BOX_GRID)
        xi, eta = (a.ravel() for a in np.meshgrid(t, t))
        N = qd.shape_functions(xi, eta)
        bbox = np.tile(np.array([0, 0, -1, -1], np.int64), (M, 1))
        drawable = np.zeros(M, bool)
        for s in range(0, M, 1 << 14):
            G = np.einsum("gi,mid->mgd", N, Pd[s:s + (1 << 14)])
            g_uv, g_ok = project_camera_frame(G, cam)
            ok = g_ok.all(axis=1)
            lo, hi = g_uv.min(axis=1), g_uv.max(axis=1)
            pad = QUAD_BOX_PAD_PX * np.maximum(1.0, (hi - lo).max(axis=1) / 100.0)[:, None]
            box = np.concatenate([np.clip(np.ceil(lo - pad - 0.5), 0, [W, H]),
                                  np.clip(np.floor(hi + pad + 0.5), -1, [W - 1, H - 1])], axis=1)
            box = np.nan_to_num(box, nan=-1).astype(np.int64)
            box[~ok] = (0, 0, -1, -1)
            bbox[s:s + len(box)] = box
            drawable[s:s + len(box)] = ok
    if mode == "q4":
        bbox[~projectable] = (0, 0, -1, -1)
    if warn:
        folded = np.flatnonzero(qd.folded(Pd))
        if folded.size:
            warnings.warn(f"camera {cam.name}: elements {_labels(folded, labels)} are folded (the surface normal "
                          "reverses inside the element: a mid-side node too far from its edge's middle?); their "
                          "pixels stay finite (the nearest root is drawn); check the mesh", RenderWarning,
                          stacklevel=3)
        bad = np.flatnonzero(~projectable & (Pd[..., 2] > NEAR_MM).any(axis=1))
        if bad.size:
            warnings.warn(f"camera {cam.name}: quadratic elements {_labels(bad, labels)} cross the camera plane or "
                          "leave the distortion model's valid radius; the q4 mode drops them (and fast mode the "
                          "pieces that do not project), the exact mode intersects them per pixel", RenderWarning,
                          stacklevel=3)
    return QuadView(camera=cam, ref_camera=ref_cam, Pd=Pd, Pr=Pr, uv=uv, ref_uv=ref_uv, bbox=bbox,
                    pieces=pieces.n if pieces is not None else 0)


def fast_local_coords(qview_ref_cam: Camera, Pr: np.ndarray, ref_uv: np.ndarray, xi0, eta0):
    """(ξ, η) on the undeformed patches Pr (K, 9, 3) (reference camera frame) of the material
    points the reference camera sees at ``ref_uv`` (K, 2): Newton on the reference ray from
    (ξ0, η0) (the fast mode's piece coordinates mapped to the patch); the start is kept where
    the ray cannot be formed or Newton does not converge (:func:`glsim.scene.quadratic.newton`)."""
    from glsim.scene.camera import pixel_to_normalized, undistort

    xn, ok = undistort(pixel_to_normalized(ref_uv, qview_ref_cam.intrinsics), qview_ref_cam.distortion.coeffs)
    p2 = Pr[..., :2] - xn[:, None, :] * Pr[..., 2:3]
    xi, eta, conv = qd.newton(p2, np.zeros((len(xn), 2)), xi0, eta0, qd.patch_size(Pr))
    good = ok & conv
    return np.where(good, xi, xi0), np.where(good, eta, eta0)


@dataclass(frozen=True, eq=False)
class PatchData:
    """What the GL backend needs to draw quadratic elements in modes exact and q4 (the view's
    elements are then the patches' linear pieces, ``pieces`` × ``pieces`` per patch, in patch
    order): the patches' control points at this step relative to the mesh's local origin
    (``local`` (M, 9, 3)), in the reference camera's frame (``ref_xr``) and as reference-image
    px (``ref_uv``), and ``extra_sag_px``, a bound of the pieces' chord error in px that the
    covers and candidate rectangles are grown by. ``token`` identifies ``local`` (caching)."""
    pieces: int
    local: np.ndarray
    ref_xr: np.ndarray
    ref_uv: np.ndarray
    extra_sag_px: float
    token: tuple


def chord_error_bound(P: np.ndarray, pieces: int) -> float:
    """An upper bound (length units of P) of the distance between patches P (M, 9, 3) and their
    bilinear pieces (``pieces`` per side): the bilinear interpolant on a cell of side h = 2/n in
    (ξ, η) is within h²/8 (max|X_ξξ| + max|X_ηη|) of the patch, and X_ξξ (linear in the row
    weights L_b(η)) is at most 1.25 × its largest row value (the Lebesgue constant of quadratic
    interpolation), likewise X_ηη."""
    if not len(P):
        return 0.0
    grid = np.empty((len(P), 3, 3, 3))                       # [m, row (η), col (ξ), d]
    for k in range(9):
        grid[:, int(qd.NODE_ETA[k]) + 1, int(qd.NODE_XI[k]) + 1] = P[:, k]
    d_xi = np.linalg.norm(grid[:, :, 0] - 2 * grid[:, :, 1] + grid[:, :, 2], axis=-1).max(axis=1)
    d_eta = np.linalg.norm(grid[:, 0] - 2 * grid[:, 1] + grid[:, 2], axis=-1).max(axis=1)
    h = 2.0 / pieces
    return float((h * h / 8 * 1.25 * (d_xi + d_eta)).max())


def q4_image_bound(Pd: np.ndarray, cam: Camera, pieces: int) -> float:
    """An upper bound (px) of how far the q4 mode's image map (the 9-node shape functions over
    the nodes' projections) strays from the projected pieces' bilinear outlines: its own chord
    error (:func:`chord_error_bound` of the projected nodes) plus its largest distance from the
    true projection at the pieces' corners (the perspective error), over the patches whose 9
    nodes project. Pd (M, 9, 3) in the camera frame."""
    uv, ok = project_camera_frame(Pd, cam)
    good = ok.all(axis=1)
    if not good.any():
        return 0.0
    uv, Pd = uv[good], Pd[good]
    t = np.linspace(-1, 1, pieces + 1)
    xi, eta = (a.ravel() for a in np.meshgrid(t, t))
    N = qd.shape_functions(xi, eta)
    image = np.einsum("gi,mid->mgd", N, uv)
    true, true_ok = project_camera_frame(np.einsum("gi,mid->mgd", N, Pd), cam)
    dev = np.where(true_ok, np.linalg.norm(image - true, axis=-1), 0.0).max()
    return float(dev) + chord_error_bound(np.pad(uv, ((0, 0), (0, 0), (0, 1))), pieces)


def patch_data(curved, view, mode: str, cache: dict) -> PatchData:
    """The GL path's payload for drawing a :class:`~glsim.backends.contract.Curved` request's
    quadratic mesh (its linear pieces, the view's elements) in its state, seen by ``view`` (a
    ViewSpec) in ``mode`` exact or q4: the state's patch points (kept in ``cache`` per state,
    with a warning naming folded elements, each time), the reference data (once) and the chord
    bound; made once per view and mode (the last VIEWS_KEPT kept), so a view rendered again
    gets the same object."""
    views, mesh = cache.setdefault("views", {}), curved.mesh
    key = (view.camera, view.ref_camera, curved.state, mode)
    hit = views.get(key)
    if hit is None:
        hit = keep(views, key, _patch_data(curved, view, mode, cache), VIEWS_KEPT)
    data, folded = hit
    if folded.size:
        warnings.warn(f"camera {view.camera.name}: elements {_labels(folded, mesh.element_labels)} are "
                      "folded (the surface normal reverses inside the element: a mid-side node too far from its "
                      "edge's middle?); their pixels stay finite (the nearest root is drawn); check the mesh",
                      RenderWarning, stacklevel=5)
    return data


def _patch_data(curved, view, mode: str, cache: dict) -> tuple[PatchData, np.ndarray]:
    """:func:`patch_data` made, and the folded elements' indices."""
    mesh, pieces, state = curved.mesh, curved.pieces, curved.state
    if "ref" not in cache:
        ref_cam = view.ref_camera
        xr = qd.patch_points(mesh.patches, to_camera(mesh.nodes, ref_cam))
        cache["ref"] = (xr, project_camera_frame(xr, ref_cam)[0])
    origin = view.mesh_geo.origin
    if cache.get("step", (None,))[0] != state:
        P = qd.patch_points(mesh.patches, curved.deformed())
        cache["step"] = (state, P - origin, chord_error_bound(P, pieces.n), np.flatnonzero(qd.folded(P)))
    _, local, chord_mm, folded = cache["step"]
    z_near = max(float(view.corner_depths().min()), NEAR_MM)
    f = float(max(view.camera.intrinsics[0], view.camera.intrinsics[1]))
    sag_px = chord_mm * f / z_near
    if mode == "q4":   # the q4 image map strays from the projected pieces: O(elements) per view
        sag_px = max(sag_px, q4_image_bound(to_camera(local + origin, view.camera), view.camera, pieces.n))
    xr, uv = cache["ref"]
    return PatchData(pieces=pieces.n, local=local, ref_xr=xr, ref_uv=uv, extra_sag_px=1.5 * sag_px,
                     token=(cache.setdefault("serial", next(_CACHES)), state)), folded


def pieces_to_patches(raster: dict, curved, cam: Camera, mode: str) -> dict:
    """An exact / q4 raster whose elements are the pieces of a :class:`~glsim.backends.contract.Curved`
    request's quadratic mesh and whose (ξ, η) are their patches' (the GL path's) → the patches:
    the piece's patch as element, (ξ, η)
    polished in float64 by :func:`glsim.scene.quadratic.newton` (on the pixel's ray, or in the
    image for q4; kept where that does not converge)."""
    r = dict(raster)
    hit = np.flatnonzero(r["element"] >= 0)
    e = curved.pieces.parent[r["element"][hit]]
    W, _ = cam.size
    q = np.column_stack([hit % W, hit // W]).astype(np.float64)
    P = qd.patch_points(curved.mesh.patches[e], to_camera(curved.deformed(), cam)) if hit.size else \
        np.zeros((0, 9, 3))
    if mode == "exact":
        xn, _ = undistort(pixel_to_normalized(q, cam.intrinsics), cam.distortion.coeffs)
        p2, target = P[..., :2] - xn[:, None, :] * P[..., 2:3], np.zeros_like(q)
    else:
        p2, target = project_camera_frame(P, cam)[0], q
    xi0, eta0 = r["xi"][hit], r["eta"][hit]
    xi, eta, ok = qd.newton(p2, target, xi0, eta0, qd.patch_size(p2))
    r["element"], r["xi"], r["eta"] = r["element"].copy(), r["xi"].copy(), r["eta"].copy()
    r["element"][hit] = e
    r["xi"][hit], r["eta"][hit] = np.where(ok, xi, xi0), np.where(ok, eta, eta0)
    return r

