"""Per-pixel training labels of one image pair (reference at step 0, deformed at ``step``), aligned
with the images, for learned DIC (optical-flow, StrainNet-like and stereo networks).

Every label comes from the renders' float64 truth — each pixel's element and (ξ, η), evaluated on
the FE mesh with the same shape functions as :class:`~glsim.io.truth.Truth`'s positions — and the
cameras' own projection (distortion included), never from the images. Pixel coordinates follow
docs/conventions.md (pixel centres at integers, (u, v) = (column, row)).

Conventions. ``flow{i}`` is *backward* flow at camera i's deformed pixels: ref(p + flow(p)) ≈ def(p).
That is StrainNet's label (Boukhtache et al.'s Speckle dataset generator makes the deformed image
as Def(x) = Ref(x + d(x)) and stores d on the deformed image's grid) and what a warp loss needs.
``forward{i}`` is the Lagrangian displacement at reference pixels, x − X, what DIC software reports
at its subset centres; for small smooth fields forward(p) ≈ −flow(p) to second order, but the
signs differ: StrainNet's d is ``flow``, not ``forward``.

Masks (uint8, 1 = valid; invalid labels hold 0):

- *covered*: the pixel shows the specimen and its material point projects into the other image
  (the other state's, or camera 1's), onto a pixel that shows the specimen too;
- *visible*: the other image's truth at the nearest pixel c to that position q shows the same
  material point. Same means: their reference positions differ by at most twice the first-order
  change of the material map over q − c, |Δu|·g_u + |Δv|·g_v, where g is the map's derivative
  (mm/px) estimated at c by the smaller one-sided difference (the smooth side of an occlusion
  edge), plus 1e-6 of the specimen's size (the positions are compared in float32). The factor 2
  lets the derivative change by up to 100 % within the 1.5-px stencil (a few per cent under
  perspective; more only at grazing views); an occluded point is many pixels' worth of material
  away from the occluder that hides it;
- *not at a discontinuity*: neighbouring pixels (4-neighbours: a pixel's footprint reaches
  halfway to them) whose labels jump, or whose elements lie on either side of a split.
  A jump: the pair's label difference differs from each available neighbouring difference along
  the same line by more than SMOOTH_CURVATURE px. For a smooth field that second difference is the
  field's curvature L'' (px/px²), and the image of a pixel averages its footprint, whose mean
  label differs from the centre's by L''/24 per axis: beyond 0.12 px/px² that is 0.005 px, half
  the 0.01 px a DIC resolves, and the centre's label no longer describes the pixel. A split: two
  elements with two distinct nodes at one place (one of each, in the undeformed mesh) — how an FE
  mesh models a crack, up to the last edge before an interior tip, whose elements also share the
  tip node; both pixels of such a pair are masked.

The specimen's outline is not a discontinuity: a pixel there is labelled by its centre's point.
With ``[exposure]`` (motion over the exposure, a rolling shutter) the labels are of the load
step's state, not of the blur around it.
"""
from __future__ import annotations

import functools
import weakref

import numpy as np
from scipy import sparse

from glsim.compose.truth import material_points
from glsim.errors import SceneError
from glsim.io.fe import specimen_mesh
from glsim.io.truth import Truth
from glsim.scene import Scene
from glsim.scene.bilinear import shape_functions
from glsim.scene.camera import Camera, distort, normalized_to_pixel
from glsim.scene.mesh import Mesh

SMOOTH_CURVATURE = 0.12    # px: largest second difference of a label between neighbouring pixels (see above)
VISIBLE_MARGIN = 2.0       # the material map's derivative may double within the visibility stencil

# Arrays are kept component-first, (3, n) points and (2, n) pixel positions: numpy's reductions over
# a trailing axis of 2 or 3 cost ten times the component-wise arithmetic.


def pair_labels(scene: Scene, step: int, ref: dict[str, Truth], deformed: dict[str, Truth], *,
                mesh: Mesh | None = None) -> dict[str, np.ndarray]:
    """The labels of one pair: ``ref[name]`` / ``deformed[name]`` are the truths of
    ``Renderer(scene).render(name, step=0 / step, truth=True)`` for one camera (2-D) or two
    (stereo; the first is camera 0, the second camera 1). ``mesh``: the renderer's
    (``Renderer.mesh``), when it was given one, or to save reading the scene's again.

    Returns float32 maps (0 where invalid) and uint8 masks (1 = valid), each (H, W[, k]) of its
    camera's images; i is the camera's index in the dicts' order:

    - ``flow{i}`` (H, W, 2) px at camera i's deformed pixels: the point's position in the reference
      image minus the pixel (backward flow, StrainNet's label), ``mask_flow{i}``;
    - ``forward{i}`` (H, W, 2) px at its reference pixels: the point's position in the deformed
      image minus the pixel (the Lagrangian displacement), ``mask_forward{i}``;
    - stereo: ``disparity_ref`` / ``disparity_def`` (H, W, 2) px at camera 0's pixels of that state:
      the point's position in camera 1's image of the same state minus the pixel, with
      ``mask_disparity_ref`` / ``mask_disparity_def``;
    - ``uvw`` (H, W, 3) mm at camera 0's reference pixels: the point's displacement at ``step`` in
      camera 0's frame, ``mask_uvw`` (covered, not at a discontinuity of ``forward0``).

    The mask rules are in the module's docstring."""
    names = _check_inputs(scene, ref, deformed)
    mesh = specimen_mesh(scene) if mesh is None else mesh
    if not (isinstance(step, (int, np.integer)) and not isinstance(step, bool) and 0 <= step < mesh.n_steps):
        raise SceneError("step", f"{step!r} is not a load step of the specimen (0…{mesh.n_steps - 1})",
                         "give the step the deformed truths were rendered at")
    cams = [scene.camera(n) for n in names]
    for cam, n in zip(cams, names):
        for which, truths in (("ref", ref), ("deformed", deformed)):
            H, W = np.shape(truths[n].mask)
            if (W, H) != cam.size:
                raise SceneError(f"{which}[{n!r}]", f"is {W} × {H} px, camera {n!r} {cam.size[0]} × {cam.size[1]}",
                                 "give the truths of Renderer(scene).render(name, truth=True) for that scene")
            last = int(np.max(truths[n].element, initial=-1))
            if last >= mesh.n_elements:
                raise SceneError(f"{which}[{n!r}]", f"names element {last}; the specimen has {mesh.n_elements}",
                                 "give the truths of this scene's renders (and its renderer's mesh)")
    nodes0, nodes_step = mesh.nodes.T.copy(), mesh.deformed(step).T.copy()
    centre = 0.5 * (nodes0.min(axis=1) + nodes0.max(axis=1))
    out: dict[str, np.ndarray] = {}
    sides = []
    for i, (cam, n) in enumerate(zip(cams, names)):
        r, d = (_Side(truths[n], mesh, nodes0, nodes_step, centre) for truths in (ref, deformed))
        sides.append((r, d))
        out[f"flow{i}"], out[f"mask_flow{i}"], _ = _label(d, d.X0, cam, r)
        out[f"forward{i}"], out[f"mask_forward{i}"], jumps = _label(r, r.Xs, cam, d)
        if i == 0:    # the displacement in camera 0's frame, where the forward label is smooth
            out["uvw"], out["mask_uvw"] = _store(r, cam.rotation @ (r.Xs - r.X0), ~jumps)
    if len(cams) == 2:
        (r0, d0), (r1, d1) = sides
        out["disparity_ref"], out["mask_disparity_ref"], _ = _label(r0, r0.X0, cams[1], r1)
        out["disparity_def"], out["mask_disparity_def"], _ = _label(d0, d0.Xs, cams[1], d1)
    return out


def _check_inputs(scene: Scene, ref: dict, deformed: dict) -> list[str]:
    """The cameras' names, in order; SceneError unless both dicts hold the same one or two cameras of
    the scene, in the same order, as Truths."""
    names = list(ref) if isinstance(ref, dict) else []
    if not 1 <= len(names) <= 2 or not isinstance(deformed, dict) or list(deformed) != names:
        got = list(deformed) if isinstance(deformed, dict) else type(deformed).__name__
        raise SceneError("ref", f"holds cameras {names}, deformed {got}", "give one camera (2-D) or two (stereo, "
                         "camera 0 first), the same in both, in the same order")
    for which, truths in (("ref", ref), ("deformed", deformed)):
        for n in names:
            if not isinstance(truths[n], Truth):
                raise SceneError(f"{which}[{n!r}]", f"is a {type(truths[n]).__name__}, not a Truth",
                                 "give Renderer(scene).render(name, step, truth=True).truth (or a truth "
                                 "file's maps())")
            scene.camera(n)
    return names


class _Side:
    """One truth's covered pixels: their flat indices, pixel coordinates (2, n) and their material
    points (3, n) world mm, undeformed (``X0``) and at the step (``Xs``): with the nodes at
    ``nodes0`` / ``nodes_step`` (3, N) by :func:`glsim.compose.truth.material_points`'s shape
    functions (what the truth's positions are made of)."""

    def __init__(self, truth: Truth, mesh: Mesh, nodes0: np.ndarray, nodes_step: np.ndarray, centre: np.ndarray):
        self.mask = np.asarray(truth.mask, bool)
        self.element = np.asarray(truth.element)
        self.shape = self.mask.shape
        self.idx = np.flatnonzero(self.mask)
        row, col = np.divmod(self.idx, self.shape[1])
        self.uv = np.empty((2, len(self.idx)))
        self.uv[0], self.uv[1] = col, row
        e = self.element.ravel()[self.idx]
        xi, eta = truth.xi.ravel()[self.idx], truth.eta.ravel()[self.idx]
        if mesh.is_quadratic:
            def evaluate(nodes):
                return np.ascontiguousarray(material_points(mesh, nodes.T, e, xi, eta).T)
        else:      # the pixels' shape functions on the nodes, a vector per coordinate (faster than (N, 3))
            n = len(e)
            shape = sparse.csr_matrix((shape_functions(xi, eta).ravel(), mesh.quads[e].ravel(),
                                       np.arange(0, 4 * n + 1, 4)), shape=(n, mesh.n_nodes))

            def evaluate(nodes):
                return np.stack([shape @ x for x in nodes])
        self.X0, self.Xs = evaluate(nodes0), evaluate(nodes_step)
        # the material point's identity: its reference position about the mesh's centre, float32 (its
        # rounding, 1e-7 of the mesh's size, is far below a pixel's footprint)
        self.identity = (self.X0 - centre[:, None]).astype(np.float32)
        self.size = float(max(-self.identity.min(initial=0.0), self.identity.max(initial=0.0)))
        self.splits = _split_pixels(self.element, mesh)

    @functools.cached_property
    def material(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The identities as maps (3, H·W) (NaN uncovered) and the material map's derivative
        estimates g_u, g_v (H·W,) mm/px: per axis the smaller one-sided difference, 0 where neither
        neighbour is covered (a 1-px strip: only an exact match passes), times VISIBLE_MARGIN. float32."""
        H, W = self.shape
        X = np.full((3, H * W), np.nan, np.float32)
        X[:, self.idx] = self.identity
        X = X.reshape(3, H, W)
        g = []
        for axis in (2, 1):
            diff = np.diff(X, axis=axis)
            d = np.sqrt(diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2])   # NaN: either uncovered
            gk = np.full((H, W), np.nan, np.float32)
            if axis == 2:
                gk[:, 1:] = d
                np.fmin(gk[:, :-1], d, out=gk[:, :-1])
            else:
                gk[1:] = d
                np.fmin(gk[:-1], d, out=gk[:-1])
            np.copyto(gk, 0.0, where=np.isnan(gk))
            gk *= VISIBLE_MARGIN
            g.append(gk.ravel())
        return X.reshape(3, -1), g[0], g[1]


def _project(X: np.ndarray, cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """World points (3, n) → pixels (2, n) and ok (n,): :func:`glsim.scene.camera.project_camera_frame`'s
    model (distortion included), the points component-first."""
    Xc = cam.rotation @ X
    Xc += cam.translation[:, None]
    front = Xc[2] > 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = Xc[:2] / np.where(front, Xc[2], 1.0)
    ok = front & (xn[0] * xn[0] + xn[1] * xn[1] < cam.distortion.valid_radius() ** 2)
    if not ok.all():
        xn[:, ~ok] = 0.0
    xd = xn if cam.distortion.is_zero else distort(xn.T, cam.distortion.coeffs).T
    return normalized_to_pixel(xd.T, cam.intrinsics).T, ok


def _label(a: _Side, X: np.ndarray, cam: Camera, b: _Side) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The label at ``a``'s covered pixels whose points are at ``X`` (3, n) world mm: their
    projection by ``cam`` minus the pixel, its mask against ``b``, the truth of the image projected
    into (covered, visible, not at a discontinuity), and the discontinuities (n,) bool.
    float32 (H, W, 2), uint8 (H, W)."""
    H, W = a.shape
    q, ok = _project(X, cam)
    label = q - a.uv
    full = np.full((2, H * W), np.nan, np.float32)   # (float32: τ is 0.12 px)
    if ok.all():
        full[:, a.idx] = label
    else:
        full[:, a.idx[ok]] = label[:, ok]
    disc = (_jumps(full.reshape(2, H, W)) | a.splits).ravel()[a.idx]
    map_, mask = _store(a, label, ok & ~disc & _visible(q, a.identity, b, max(a.size, b.size)))
    return map_, mask, disc


def _visible(q: np.ndarray, X0: np.ndarray, b: _Side, size: float) -> np.ndarray:
    """Whether the points of identities ``X0`` (3, n), projected at ``q`` (2, n) px into ``b``'s
    image, are what ``b`` shows at the nearest pixel (see the module's docstring); ``size``: the
    identities' largest coordinate (mm), for their rounding."""
    Hb, Wb = b.shape
    c = np.rint(q)
    off = np.abs(q - c).astype(np.float32)
    c = c.astype(np.int64)
    inside = (c[0].astype(np.uint64) < Wb) & (c[1].astype(np.uint64) < Hb)     # (negatives wrap round)
    k = c[1] * Wb + c[0]
    k[~inside] = 0
    Xb, gu, gv = b.material
    tol = off[0] * gu[k] + off[1] * gv[k] + np.float32(1e-6 * (1.0 + size))   # (float32 identities, with room)
    d2 = (Xb[0, k] - X0[0]) ** 2 + (Xb[1, k] - X0[1]) ** 2 + (Xb[2, k] - X0[2]) ** 2
    return inside & (d2 <= tol * tol)                  # (NaN where b's pixel is uncovered: not visible)


def _store(a: _Side, values: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` (k, n) at ``a``'s covered pixels as a float32 (H, W, k) map, 0 where not ``valid``,
    and the uint8 mask."""
    H, W = a.shape
    k = len(values)
    out = np.zeros((H * W, k), np.float32)
    out[a.idx] = values.T
    mask = np.zeros(H * W, np.uint8)
    mask[a.idx] = valid
    out[a.idx[~valid]] = 0.0         # (the few invalid afterwards: cheaper than compressing all)
    return out.reshape(H, W, k), mask.reshape(H, W)


def _jumps(L: np.ndarray) -> np.ndarray:
    """(H, W) bool: both pixels of every neighbouring pair whose label difference differs from each
    available neighbouring difference along its line by more than SMOOTH_CURVATURE px (NaN labels
    (2, H, W): unavailable)."""
    flags = np.zeros(L.shape[1:], bool)
    t2 = np.float32(SMOOTH_CURVATURE ** 2)
    for ax in (0, 1):
        n = flags.shape[ax]
        if n < 3:
            continue
        lab = L.transpose(1, 2, 0)                                   # (H, W, 2): ax indexes H or W
        dd = _along(lab, ax, 2, n) - 2 * _along(lab, ax, 1, n - 1) + _along(lab, ax, 0, n - 2)
        dd2 = dd[..., 0] * dd[..., 0] + dd[..., 1] * dd[..., 1]       # [k]: pair k + 1 against pair k
        big = dd2 > t2
        either = ~(dd2 <= t2)                                          # big, or unavailable (NaN)
        # pair k (pixels k, k + 1) against pair k − 1 (dd2[k − 1]) and pair k + 1 (dd2[k]); none beyond the ends
        jump = np.empty(big.shape[:ax] + (n - 1,) + big.shape[ax + 1:], bool)
        _along(jump, ax, 0, 1)[...] = _along(big, ax, 0, 1)
        _along(jump, ax, n - 2, n - 1)[...] = _along(big, ax, n - 3, n - 2)
        _along(jump, ax, 1, n - 2)[...] = (_along(either, ax, 0, n - 3) & _along(either, ax, 1, n - 2)
                                           & (_along(big, ax, 0, n - 3) | _along(big, ax, 1, n - 2)))
        _mark_pairs(flags, ax, jump)
    return flags


def _along(a: np.ndarray, axis: int, lo: int, hi: int) -> np.ndarray:
    """``a`` sliced lo:hi along ``axis`` (a view)."""
    return a[(slice(None),) * axis + (slice(lo, hi),)]


def _mark_pairs(flags: np.ndarray, ax: int, pairs: np.ndarray) -> None:
    """Set in ``flags`` (H, W) both pixels of the neighbouring pairs along ``ax`` that ``pairs`` (one
    shorter along ``ax``) holds."""
    n = flags.shape[ax]
    first, second = _along(flags, ax, 0, n - 1), _along(flags, ax, 1, n)
    first |= pairs
    second |= pairs


def _split_pixels(element: np.ndarray, mesh: Mesh) -> np.ndarray:
    """(H, W) bool: both pixels of every neighbouring pair on two elements with two distinct nodes at
    the same place in the undeformed mesh (one of each): either side of a split."""
    flags = np.zeros(element.shape, bool)
    canon = _canonical_nodes(mesh)
    if canon is None:
        return flags
    quads = mesh.quads
    for ax in (0, 1):
        n = element.shape[ax]
        a, b = _along(element, ax, 0, n - 1), _along(element, ax, 1, n)
        pair = (a >= 0) & (b >= 0) & (a != b)
        qa, qb = quads[a[pair]], quads[b[pair]]
        # two distinct nodes at one place: the elements lie on either side of a split, even where
        # they also share a node (the last edge before a crack's interior tip shares the tip)
        apart = ((canon[qa][:, :, None] == canon[qb][:, None, :]) & (qa[:, :, None] != qb[:, None, :])).any(axis=(1, 2))
        split = np.zeros(a.shape, bool)
        split[pair] = apart
        _mark_pairs(flags, ax, split)
    return flags


_CANONICAL: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()   # mesh → _canonical_nodes(mesh)


def _canonical_nodes(mesh: Mesh) -> np.ndarray | None:
    """Each node's first node at the same place (N,) (coordinates equal to 1e-9 of the mesh's
    extent: duplicated nodes), or None when no two nodes coincide; kept while the mesh lives."""
    if mesh in _CANONICAL:
        return _CANONICAL[mesh]
    nodes = mesh.nodes
    scale = 1e-9 * max(float(np.ptp(nodes, axis=0).max()), 1e-300)
    key = np.round((nodes - nodes.min(axis=0)) / scale)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    canon = None if len(first) == len(nodes) else first[inverse.ravel()]
    _CANONICAL[mesh] = canon
    return canon
