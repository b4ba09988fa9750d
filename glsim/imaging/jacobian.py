"""Stage "raster → image Jacobian": the derivative of the noise-free image with respect to every
nodal displacement component, in float64 numpy from a per-sample raster (docs/jacobian.md).

A sample's grey is g = I(r(ξ, η)): the reference image I (its interpolant) at the reference
point r of the local coordinates (ξ, η) where the sample maps into its element. Only (ξ, η)
depends on the deformed nodes X_k (camera frame), through the mapping's equation F(ξ, η, X) = 0:

- ``exact``: the sample's ray (x, y, 1) meets the deformed patch, F = A·P(ξ, η) with
  A = [[1, 0, −x], [0, 1, −y]] and P = Σ N_k X_k; r = π_ref(Σ N_k X̄_k) (X̄_k undeformed, in the
  reference camera's frame);
- ``q4``: the sample's pixel point q is the projected element's bilinear image,
  F = Σ N_k π(X_k) − q; r = Σ N_k π_ref(X̄_k).

Implicit differentiation: ∂(ξ, η)/∂X_k = −(∂F/∂(ξ, η))⁻¹ ∂F/∂X_k, with ∂F/∂X_k = N_k A (exact)
or N_k ∂π/∂X(X_k) (q4); then ∂g/∂X_k = ∇I · ∂r/∂(ξ, η) · ∂(ξ, η)/∂X_k, and ∂X_k/∂u_k = R (the
camera's rotation: displacements are in the world frame). Coverage does not move with the
nodes between samples, so background samples and the mask contribute nothing.

Quadratic elements: the same over a patch's 9 control points and their Q9 shape functions; a
derived centre (Q8, T6) passes its derivative to the 8 nodes with its weights.

Columns are node-major: 3·node + c for the components (u_x, u_y, u_z) of ``mesh.nodes[node]``;
rows are the pixels v·W + u. Grey levels (of full scale) per mm. The same per-sample quantities
give the derivative with respect to the rendering camera's pose, intrinsics and distortion
(:func:`rig_derivatives`).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy import sparse

from glsim.errors import SceneError
from glsim.scene import Render, Scene
from glsim.scene import bilinear as bl
from glsim.scene import quadratic as qd
from glsim.scene.camera import (Camera, distort, distort_jacobian, pixel_to_normalized, project_camera_frame, to_camera,
                                undistort)

# optional tables the Jacobian takes (check_request refuses any other by name): it is of the
# noise-free image, over the exposure (the sub-frames' mean), lit, through the depth of field
# (glsim.effects.dof.through_blur) and through the camera effects that act on it linearly
# (glsim.compose.chain.through_camera_effects)
UNREFUSED = ("noise", "vignetting", "psf", "sensor", "exposure", "lighting", "optics")
CHUNK = 1 << 18          # samples differentiated at once (bounds memory: ~100 doubles each)


def check_request(scene: Scene, opts: Render, dots=None) -> None:
    """SceneError naming what ``jacobian=True`` cannot differentiate: a procedural speckle (the
    reference's ``dots``) with a hard edge (and any optional table not in UNREFUSED)."""
    for f in dataclasses.fields(scene):
        if f.default is None and getattr(scene, f.name) is not None and f.name not in UNREFUSED:
            raise SceneError(f.name, "the image Jacobian does not differentiate this effect",
                             f"remove [{f.name}] or render without jacobian")
    if opts.interpolation == "procedural" and dots is not None and dots.edge_px == 0:
        raise SceneError("speckle.edge_px", "is 0: a hard-edged procedural speckle's grey jumps at the dots' edges, "
                         "so the image Jacobian would be zero everywhere else", "give the dots a smooth edge "
                         "(edge_px > 0), or choose an interpolated reference (cubic, bspline3, bspline5)")


def sample_camera(cam: Camera, s: int) -> Camera:
    """The camera whose pixel centres are ``cam``'s s×s samples per pixel
    (:func:`glsim.scene.camera.pixel_grid`): size ×s, fx, fy, skew ×s, c' = s·(c + ½) − ½;
    the same rays (to rounding)."""
    if s == 1:
        return cam
    W, H = cam.size
    return dataclasses.replace(cam, size=(W * s, H * s), fx=cam.fx * s, fy=cam.fy * s, skew=cam.skew * s,
                               cx=s * (cam.cx + 0.5) - 0.5, cy=s * (cam.cy + 0.5) - 0.5)


def projection_jacobian(X: np.ndarray, cam: Camera) -> np.ndarray:
    """∂uv/∂X (..., 2, 3) px per mm of :func:`glsim.scene.camera.project_camera_frame` at
    camera-frame points X (..., 3): intrinsics · distortion Jacobian · perspective division."""
    z = X[..., 2]
    xn = X[..., :2] / z[..., None]
    dpersp = np.zeros(X.shape[:-1] + (2, 3))
    dpersp[..., 0, 0] = dpersp[..., 1, 1] = 1.0 / z
    dpersp[..., :, 2] = -xn / z[..., None]
    K2 = np.array([[cam.fx, cam.skew], [0.0, cam.fy]])
    return K2 @ distort_jacobian(xn, cam.distortion.coeffs) @ dpersp


def _shape_derivatives(xi, eta, nodes: int = 4):
    """(N, ∂N/∂ξ, ∂N/∂η), each (n, nodes), of the Q4 shape functions (FE corner order) or, for
    9 nodes, of the Q9 patch's (glsim.scene.quadratic)."""
    if nodes == 9:
        return (qd.shape_functions(xi, eta), *qd.shape_derivatives(xi, eta))
    return (bl.shape_functions(xi, eta), *bl.shape_derivatives(xi, eta))


def _tangents(N_xi, N_eta, P):
    """(…, D, 2): the columns ∂P/∂ξ, ∂P/∂η of corners P (n, 4, D)."""
    return np.stack([np.einsum("nk,nkd->nd", N_xi, P), np.einsum("nk,nkd->nd", N_eta, P)], -1)


def _left_solve(w, M):
    """w · M⁻¹ (n, 2) for row vectors w (n, 2) and 2×2 matrices M (n, 2, 2); 0 where M is
    singular (a ray grazing its element: no finite derivative)."""
    a, b, c, d = M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1]
    det = (a * d - b * c)[:, None]
    num = np.column_stack([w[:, 0] * d - w[:, 1] * c, w[:, 1] * a - w[:, 0] * b])
    return np.divide(num, det, out=np.zeros_like(num), where=det != 0)


def _ray_matrix(ray) -> np.ndarray:
    """A (n, 2, 3) = [[1, 0, −x], [0, 1, −y]] of the rays (x, y, 1): A·X = 0 on the ray."""
    A = np.zeros((len(ray), 2, 3))
    A[:, 0, 0] = A[:, 1, 1] = 1.0
    A[:, :, 2] = -ray
    return A


def sensitivities(mode: str, w, Xd, xi, eta, ray, cam: Camera):
    """Implicit differentiation of the mapping F(ξ, η, X) = 0 given w = ∂g/∂(ξ, η) (n, 2): the
    shape functions N (n, 4), v = w · (∂F/∂(ξ, η))⁻¹ (n, 2) and the corners' ∂g/∂X_k =
    −v · ∂F/∂X_k (n, 4, 3) per mm, for the deformed corners Xd (n, 4, 3) in the camera frame.
    Mode ``exact`` on the samples' rays ``ray`` (n, 2) (undistorted normalized), ``q4`` in
    camera ``cam``'s image."""
    N, N_xi, N_eta = _shape_derivatives(xi, eta, Xd.shape[1])
    if mode == "exact":
        A = _ray_matrix(ray)
        v = _left_solve(w, A @ _tangents(N_xi, N_eta, Xd))
        return N, v, -N[..., None] * np.einsum("nl,nlc->nc", v, A)[:, None, :]
    v = _left_solve(w, _tangents(N_xi, N_eta, project_camera_frame(Xd, cam)[0]))
    return N, v, -N[..., None] * np.einsum("nl,nklc->nkc", v, projection_jacobian(Xd, cam))


def distortion_coefficient_jacobian(xn, k) -> np.ndarray:
    """∂xd/∂k (..., 2, 12) of :func:`glsim.scene.camera.distort` with respect to its 12
    coefficients (k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4) at undistorted ``xn``."""
    x, y = xn[..., 0], xn[..., 1]
    k = np.asarray(k, dtype=np.float64)
    r2 = x * x + y * y
    den = 1.0 + r2 * (k[5] + r2 * (k[6] + r2 * k[7]))
    radial = (1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[4]))) / den
    J = np.zeros(xn.shape[:-1] + (2, 12))
    for num_col, den_col, p in ((0, 5, r2), (1, 6, r2 * r2), (4, 7, r2 * r2 * r2)):
        J[..., 0, num_col], J[..., 1, num_col] = x * p / den, y * p / den
        J[..., 0, den_col], J[..., 1, den_col] = -x * radial * p / den, -y * radial * p / den
    J[..., 0, 2], J[..., 1, 2] = 2.0 * x * y, r2 + 2.0 * y * y
    J[..., 0, 3], J[..., 1, 3] = r2 + 2.0 * x * x, 2.0 * x * y
    J[..., 0, 8], J[..., 0, 9], J[..., 1, 10], J[..., 1, 11] = r2, r2 * r2, r2, r2 * r2
    return J


RIG_COLUMNS = ("rx", "ry", "rz", "tx", "ty", "tz", "fx", "fy", "cx", "cy", "skew",
               "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4")


def rig_derivatives(mode: str, N, v, c, Xd, cam: Camera, s: int, q=None, ray=None, dP=None) -> np.ndarray:
    """∂g/∂(camera parameters) (n, 23) in :data:`RIG_COLUMNS`' order, from :func:`sensitivities`'s
    N, v (of the sample camera) and camera-frame corner derivatives c. Pose: a rotation vector ω
    applied on the left (R ← exp([ω]×)·R, per radian) and t ← t + τ (per mm) move every corner by
    ω × (X_k − t) + τ: ∂g/∂τ = Σ c_k, ∂g/∂ω = Σ (X_k − t) × c_k. Intrinsics (per px) and
    distortion (per unit) of ``cam``: ``exact`` through the ray of the pixel point ``q`` (n, 2,
    ``cam``'s px; F = A(x_n)·P, ∂F/∂x_n = −P_z), ``q4`` and ``fast`` through the corners'
    projections (``dP``: fast's ∂g/∂(corner's pixel) (n, 4, 2) per ``cam`` px, :func:`fast_sensitivities`;
    q4's is −s·v·N_k)."""
    k = cam.distortion.coeffs
    fx, fy, skew = cam.fx, cam.fy, cam.skew
    Y = Xd - np.asarray(cam.t)
    out = np.empty((len(c), 23))
    out[:, 3:6] = c.sum(axis=1)
    out[:, 0:3] = np.cross(Y, c).sum(axis=1)
    if mode == "exact":
        Pz = np.einsum("nk,nk->n", N, Xd[..., 2])
        out[:, 6:] = np.einsum("nl,nlp->np", v * Pz[:, None], ray_parameter_jacobian(cam, q, ray))
        return out
    xn = Xd[..., :2] / Xd[..., 2:3]
    xdk = distort(xn, k)
    dpi = np.zeros(Xd.shape[:2] + (2, 5))
    dpi[..., 0, 0], dpi[..., 1, 1], dpi[..., 0, 2], dpi[..., 1, 3], dpi[..., 0, 4] = \
        xdk[..., 0], xdk[..., 1], 1.0, 1.0, xdk[..., 1]
    K2 = np.array([[fx, skew], [0.0, fy]])
    dpik = K2 @ distortion_coefficient_jacobian(xn, k)
    dP = -s * N[..., None] * v[:, None, :] if dP is None else dP
    out[:, 6:11] = np.einsum("nkl,nklp->np", dP, dpi)
    out[:, 11:] = np.einsum("nkl,nklp->np", dP, dpik)
    return out


def ray_parameter_jacobian(cam: Camera, q, ray=None) -> np.ndarray:
    """∂x_n/∂(intrinsics, distortion) (n, 2, 17), in RIG_COLUMNS' order from ``fx``, of the
    undistorted normalized rays x_n = undistort(K⁻¹q) of ``cam``'s pixel points q (n, 2):
    (∂distort/∂x_n)⁻¹ (∂x_d/∂(fx, fy, cx, cy, skew) | −∂distort/∂k); 0 where the distortion's
    Jacobian is singular. ``ray``: the rays, if known."""
    k = cam.distortion.coeffs
    fx, fy, skew = cam.fx, cam.fy, cam.skew
    ray = sample_rays(cam, q) if ray is None else ray
    xd = pixel_to_normalized(q, cam.intrinsics)
    dxd = np.zeros((len(q), 2, 17))
    dxd[:, 1, 1], dxd[:, 1, 3] = -xd[:, 1] / fy, -1.0 / fy
    dxd[:, 0, 0], dxd[:, 0, 2], dxd[:, 0, 4] = -xd[:, 0] / fx, -1.0 / fx, -xd[:, 1] / fx
    dxd[:, 0, 1], dxd[:, 0, 3] = -skew * dxd[:, 1, 1] / fx, -skew * dxd[:, 1, 3] / fx
    dxd[:, :, 5:] = -distortion_coefficient_jacobian(ray, k)
    M = distort_jacobian(ray, k)
    det = M[:, 0, 0] * M[:, 1, 1] - M[:, 0, 1] * M[:, 1, 0]
    inv = np.stack([np.stack([M[:, 1, 1], -M[:, 0, 1]], -1), np.stack([-M[:, 1, 0], M[:, 0, 0]], -1)], 1)
    inv = np.divide(inv, det[:, None, None], out=np.zeros_like(inv), where=det[:, None, None] != 0)
    return inv @ dxd


def fast_triangles(P, q):
    """Mode fast's triangle of each sample point q (n, 2) in quads of projected corners P (n, 4,
    2): the index into glsim.scene.bilinear.FAST_TRIANGLES (the first that owns q under the tie
    rule, as the oracle draws; where none does — a backend's raster snapped otherwise — the one q
    lies deepest in) and q's screen-space barycentric coordinates λ (n, 3) in it."""
    lams, hits, taken = [], [], np.zeros(len(q), bool)
    for tri in bl.FAST_TRIANGLES:
        lam, hit = bl.triangle_barycentric(P, q, tri, taken)
        lams.append(lam)
        hits.append(hit)
        taken |= hit
    t = np.where(hits[0], 0, np.where(hits[1], 1, np.argmax([lam.min(-1) for lam in lams], axis=0)))
    return t, np.where((t == 0)[:, None], lams[0], lams[1])


FAST_CORNERS = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])   # (ξ, η) of the corners


def fast_sensitivities(grad, q, P, Pr, Xd, PJ, depth: bool = False, shading=None, e=None, t=None):
    """Mode fast's derivatives of a sample's grey g = I(r): r = Σ w_j R_j over its triangle's
    corners (glsim.backends.cpu's perspective-correct weights w_j = a_j/S, a_j = λ_j/z_j, S = Σ a_m,
    of the screen-space barycentrics λ of the sample point q (n, 2) in the corners' projections
    P_j (n, 4, 2), R_j their reference points ``Pr`` (n, 4, 2), z_j the depths of the corners Xd
    (n, 4, 3, camera frame)). A value f(a) of the triangle moves with its corners through ψ_j =
    ∂f/∂a_j and ∂λ_j/∂P_i = −λ_i ∇_q λ_j: ∂f/∂P_i = −λ_i Σ_j (ψ_j/z_j) ∇_q λ_j, ∂f/∂z_i =
    −ψ_i λ_i/z_i² — for the grey ψ_j = (∇I·R_j − Σ w_m ∇I·R_m)/S. Returns the camera-frame corner
    derivatives c (n, 4, 3) per mm (through the corners' projection Jacobians PJ (n, 4, 2, 3),
    :func:`projection_jacobian` of the camera whose pixels q and P are), ∂f/∂P (n, 4, 2) per px
    (the corner off the triangle 0), what the lighting adds, and the depth's.

    ``shading`` (:class:`glsim.effects.lighting.ShadingTerms`, elements ``e``, the camera's
    translation ``t``): the oracle lights the point (ξ, η) = Σ w_j C_j of the triangle's corners'
    (ξ, η) C_j — X = Σ N_k X_k and Ñ interpolated there — so g' = combine(g, I(X, Ñ)) adds
    ∂g'/∂(ξ, η)·(C_j − (ξ, η))/S to ψ, and ∂g'/∂X·N_k to c; returns (dn (n, 4, 3): ∂g'/∂n_j, src,
    the pose columns' term) as :func:`lit_sensitivities` does, else None. ``depth``: the sample's
    depth 1/S (n,) (the oracle's) and its (c, ∂/∂P), ψ_j = −1/S²; else None."""
    n = len(q)
    tp, lam = fast_triangles(P, q)
    tri, rows = np.array(bl.FAST_TRIANGLES)[tp], np.arange(n)[:, None]
    zt, Pt, Rt = Xd[rows, tri, 2], P[rows, tri], Pr[rows, tri]
    a = lam / zt
    S = a.sum(-1)[:, None]
    w = a / S
    d1, d2 = Pt[:, 1] - Pt[:, 0], Pt[:, 2] - Pt[:, 0]
    den = bl._cross(d1, d2)[:, None]
    g1 = np.divide(np.column_stack([d2[:, 1], -d2[:, 0]]), den, out=np.zeros((n, 2)), where=den != 0)
    g2 = np.divide(np.column_stack([-d1[:, 1], d1[:, 0]]), den, out=np.zeros((n, 2)), where=den != 0)
    grad_lam, PJt = np.stack([-g1 - g2, g1, g2], 1), PJ[rows, tri]

    def through(psi):   # (c, ∂f/∂P) of a value with ∂f/∂a = psi (n, 3)
        dPt = -lam[..., None] * np.einsum("nk,nkd->nd", psi / zt, grad_lam)[:, None, :]
        ct = np.einsum("nkd,nkdc->nkc", dPt, PJt)
        ct[..., 2] -= psi * lam / zt ** 2
        c, dP = np.zeros((n, 4, 3)), np.zeros((n, 4, 2))
        c[rows, tri], dP[rows, tri] = ct, dPt
        return c, dP

    r = np.einsum("nk,nkd->nd", w, Rt)
    G = np.einsum("nd,nkd->nk", grad(r), Rt)
    psi, lit = (G - (w * G).sum(-1)[:, None]) / S, None
    if shading is not None:
        C = FAST_CORNERS[tri]
        xe = np.einsum("nk,nkd->nd", w, C)
        N, gg, gX, w_xe, dn, src, pose = lit_point(shading, e, xe[:, 0], xe[:, 1], Xd, r, t)
        psi = gg[:, None] * psi + (np.einsum("nl,nkl->nk", w_xe, C) - (w_xe * xe).sum(-1)[:, None]) / S
        lit = (dn, src, pose)
    c, dP = through(psi)
    if shading is not None:
        c = c + N[..., None] * gX[:, None, :]
    return c, dP, lit, (1.0 / S[:, 0], *through(np.broadcast_to(-1.0 / S ** 2, lam.shape))) if depth else None


def reference_point(mode: str, Xr, ref_cam: Camera, xi, eta):
    """The reference point r (n, 2) px and ∂r/∂(ξ, η) (n, 2, 2), in float64 from (ξ, η):
    ``exact`` projects the undeformed patch Xr (n, 4 or 9, 3, reference camera frame) at (ξ, η);
    ``q4`` interpolates its nodes' projections with the shape functions."""
    N, N_xi, N_eta = _shape_derivatives(xi, eta, Xr.shape[1])
    at = bl.bilinear if Xr.shape[1] == 4 else lambda P, x, y: np.einsum("nk,nkd->nd", N, P)   # noqa: E731
    if mode == "exact":
        X = at(Xr, xi, eta)
        return project_camera_frame(X, ref_cam)[0], projection_jacobian(X, ref_cam) @ _tangents(N_xi, N_eta, Xr)
    corners = project_camera_frame(Xr, ref_cam)[0]
    return at(corners, xi, eta), _tangents(N_xi, N_eta, corners)


def sample_points(W: int, s: int, index: np.ndarray, aperture: float = 1.0) -> np.ndarray:
    """The samples at flat indices ``index`` of the sample camera (:func:`sample_camera`) of a
    camera W px wide as that camera's pixel points (n, 2): pixel c's sample k along an axis at
    c + aperture·((k + ½)/s − ½) (glsim.scene.camera.pixel_grid's)."""
    fi, fj = index % (W * s), index // (W * s)
    off = lambda f: f // s + aperture * ((f % s + 0.5) / s - 0.5)   # noqa: E731
    return np.column_stack([off(fi), off(fj)]).astype(np.float64)


def shifted_cameras(cam: Camera, s: int, aperture: float) -> list[list[Camera]]:
    """Per sample offset (row l, column k of the s × s) ``cam`` shifted so that its pixel
    centres are those samples: c' = c − aperture·((k + ½)/s − ½) (the same rays)."""
    off = [aperture * ((k + 0.5) / s - 0.5) for k in range(s)]
    return [[dataclasses.replace(cam, cx=cam.cx - du, cy=cam.cy - dv) for du in off] for dv in off]


def sample_rays(cam: Camera, q: np.ndarray) -> np.ndarray:
    """Undistorted normalized rays (n, 2) of ``cam``'s pixel points ``q`` (n, 2)."""
    return undistort(pixel_to_normalized(q, cam.intrinsics), cam.distortion.coeffs)[0]


@dataclasses.dataclass(frozen=True)
class MeshState:
    """The mesh differentiated: ``nodes`` and ``deformed`` (N, 3) world mm, its ``quads`` and a
    quadratic mesh's ``patches`` (its (ξ, η) are the patches'; None for linear elements)."""
    nodes: np.ndarray
    deformed: np.ndarray
    quads: np.ndarray
    patches: np.ndarray | None = None


@dataclasses.dataclass(frozen=True)
class JacobianOptions:
    """How :func:`image_jacobian` reads its raster and what it returns beside J."""
    mode: str = "exact"       # exact or q4: (ξ, η) through the mapping; fast: the sample's triangle
    samples: int = 1          # s: the raster's samples per pixel along each axis
    aperture: float = 1.0     # √ of a fill factor: the samples' offsets' scale (:func:`sample_points`)
    rig: bool = False         # also the derivative with respect to the camera's parameters
    depth: bool = False       # also each sample's depth and the pixels' depth derivatives


def image_jacobian(cam: Camera, ref_cam: Camera, mesh: MeshState, raster: dict, grad,
                   options: JacobianOptions = JacobianOptions(), shading=None):
    """The image Jacobian (W·H × 3·nodes, CSR, grey levels per mm) of ``cam`` from ``raster``:
    flat ``element``, ``xi``, ``eta`` (float64) over the (W·s)·(H·s) samples of
    :func:`sample_camera` (element −1: background; s = ``options.samples``); the reference point
    is recomputed from them (mode exact or q4; in fast from the element's triangle at the sample
    point, :func:`fast_sensitivities`: its (ξ, η) are not used). ``grad(uv)`` the reference
    interpolant's gradient (grey per px). A pixel's row is the mean of its s² samples'
    derivatives. ``shading``: the lighting's :class:`glsim.effects.lighting.ShadingTerms`
    (:func:`lit_sensitivities`). Returns it; if ``options.rig``, the W·H × 23 CSR Jacobian with
    respect to ``cam``'s parameters (:func:`rig_derivatives`), else None; if ``options.depth``,
    (z, J_z, J_z rig): each sample's camera-frame depth (flat, 0 on the background; mm) and the
    derivative of each pixel's depth — the mean of its covered samples', what the depth of field
    blurs with — with respect to the nodal displacements (W·H × 3·nodes, CSR, mm per mm) and, if
    rig, the camera's parameters (W·H × 23), else None. ``options.aperture`` < 1: the samples
    lie at c + aperture·((k + ½)/s − ½) of their pixel c (:func:`sample_points`; the raster in
    the sample camera's order, :func:`shifted_cameras`)."""
    mode, s, aperture, rig, depth = options.mode, options.samples, options.aperture, options.rig, options.depth
    nodes, deformed, quads, patches = mesh.nodes, mesh.deformed, mesh.quads, mesh.patches
    W, H = cam.size
    scam = sample_camera(cam, s)
    R = cam.rotation
    hit = np.flatnonzero(raster["element"] >= 0)
    parts, rig_parts, normal_parts, depth_parts, depth_rig_parts, needed = [], [], [], [], [], []
    shape = (W * H, 3 * len(nodes))
    if depth:
        z = np.zeros(len(raster["element"]))
        covered = np.bincount(hit // (W * s) // s * W + hit % (W * s) // s, minlength=W * H)
    if mode == "fast":   # per node once: the projections (cam's pixels), the reference points, ∂π/∂X
        Xc = to_camera(deformed, scam)
        nodal = (project_camera_frame(Xc, cam)[0], project_camera_frame(to_camera(nodes, ref_cam), ref_cam)[0],
                 projection_jacobian(Xc, cam))
    for k in range(0, len(hit), CHUNK):
        idx = hit[k:k + CHUNK]
        e, xi, eta = raster["element"][idx], raster["xi"][idx], raster["eta"][idx]
        Xd = qd.element_points(quads, patches, e, to_camera(deformed, scam))
        q = sample_points(W, s, idx, aperture)    # the samples in cam's pixels
        ray = sample_rays(cam, q) if mode == "exact" else None
        fi, fj = idx % (W * s), idx // (W * s)
        pixel = fj // s * W + fi // s
        dP = None
        if mode == "fast":   # (a quadratic mesh's pieces are linear elements here)
            N = v = None
            corners = quads[e]
            c, dP, lit, fast_depth = fast_sensitivities(grad, q, nodal[0][corners], nodal[1][corners], Xd,
                                                        nodal[2][corners], depth, shading, e, cam.t)
            if lit is not None:
                dn, src, pose = lit
        else:
            Xr = qd.element_points(quads, patches, e, to_camera(nodes, ref_cam))
            r, dr = reference_point(mode, Xr, ref_cam, xi, eta)
            w = np.einsum("nc,ncl->nl", grad(r), dr)                                # ∂g/∂(ξ, η)
            if shading is None:
                N, v, c = sensitivities(mode, w, Xd, xi, eta, ray, scam)
            else:
                N, v, c, dn, src, pose = lit_sensitivities(mode, w, Xd, xi, eta, ray, scam, shading, e, r)
        if shading is not None:
            cols = (3 * src[..., None] + np.arange(3)).ravel()
            normal_parts.append(sparse.coo_matrix(((dn @ R).ravel() / (s * s), (np.repeat(pixel, 12), cols)),
                                                  shape=(W * H, 3 * shading.sources)).tocsr())
            needed.append(np.unique(src))
        parts.append(_node_part(c, e, quads, patches, R, pixel, np.full(len(idx), 1.0 / (s * s)), shape))
        if depth:
            if mode == "fast":   # z = 1/Σ λ_j/z_j (fast_sensitivities)
                z[idx], cz, dPz = fast_depth
                vz = None
            else:   # z = Σ N_k Z_k, through (ξ, η) and directly
                Nz, Nz_xi, Nz_eta = _shape_derivatives(xi, eta, Xd.shape[1])
                z[idx] = np.einsum("nk,nk->n", Nz, Xd[..., 2])
                wz = np.column_stack([np.einsum("nk,nk->n", Nz_xi, Xd[..., 2]),
                                      np.einsum("nk,nk->n", Nz_eta, Xd[..., 2])])
                _, vz, cz = sensitivities(mode, wz, Xd, xi, eta, ray, scam)
                cz[..., 2] += Nz
                dPz = None
            depth_parts.append(_node_part(cz, e, quads, patches, R, pixel, 1.0 / covered[pixel], shape))
        if rig:
            values = rig_derivatives(mode, N, v, c, Xd, cam, s, q, ray, dP)
            if shading is not None:
                values[:, :6] += pose
            rig_parts.append(_rig_part(values / (s * s), pixel, W * H))
            if depth:   # the depth in the camera's frame moves with its pose, and (ξ, η) with all its parameters
                depth_rig_parts.append(_rig_part(rig_derivatives(mode, N, vz, cz, Xd, cam, s, q, ray, dPz)
                                                 / covered[pixel][:, None], pixel, W * H))
    J = _total(parts, shape)
    if shading is not None and normal_parts:   # through the corner normals' own dependence on the nodes
        J = J + _total(normal_parts, (W * H, 3 * shading.sources)) @ shading.D(np.concatenate(needed))
    rig_shape = (W * H, len(RIG_COLUMNS))
    return (J, _total(rig_parts, rig_shape) if rig else None,
            (z, _total(depth_parts, shape), _total(depth_rig_parts, rig_shape) if rig else None) if depth else None)


def _rig_part(values, pixel, rows: int) -> sparse.csr_matrix:
    """Per-sample rig derivatives (n, 23) as a CSR matrix (rows × 23), sample i in row ``pixel[i]``."""
    return sparse.coo_matrix((values.ravel(), (np.repeat(pixel, values.shape[1]), np.tile(np.arange(values.shape[1]),
                                                                                           len(pixel)))),
                             shape=(rows, values.shape[1])).tocsr()


def _node_part(c, e, quads, patches, R, pixel, weight, shape) -> sparse.csr_matrix:
    """Per-sample derivatives c (n, corners, 3; camera frame) of elements ``e`` as a CSR matrix
    of ``shape`` (pixels × 3·nodes, world frame: ·R), each sample's row ``pixel`` scaled by its
    ``weight`` (n,) — a quadratic mesh's derived centres spread (glsim.scene.quadratic.fold_centres)."""
    corners, cn = (quads[e], c) if patches is None else qd.fold_centres(patches[e], c)
    values = cn @ R * weight[:, None, None]                                          # per world mm
    cols = (3 * corners[..., None] + np.arange(3)).ravel()
    return sparse.coo_matrix((values.ravel(), (np.repeat(pixel, 3 * corners.shape[1]), cols)), shape=shape).tocsr()


def lit_sensitivities(mode: str, w, Xd, xi, eta, ray, cam: Camera, shading, e, r):
    """:func:`sensitivities` of a lit sample's grey g' = combine(g, I(X, Ñ)) (docs/jacobian.md):
    X = Σ N_k X_k (the element's corners or patch's control points Xd) and Ñ = Σ w_j n_j (the
    corner normals of the element or of the linear piece holding the sample:
    ``shading.normals_at``) move with (ξ, η) and with the nodes, so ∂g'/∂(ξ, η) = ∂g'/∂g·w +
    ∂g'/∂X·∂X/∂(ξ, η) + ∂g'/∂Ñ·∂Ñ/∂(ξ, η) enters the implicit differentiation, and the corners
    gain ∂g'/∂X·N_k. Also returns dn (n, 4, 3): ∂g'/∂n_j, camera frame, and src (n, 4): the
    normals' row blocks in ``shading.D`` (their own derivatives), and what
    the lighting adds to :func:`rig_derivatives`' pose columns (n, 6: ω, τ): a pose change moves
    the corners, normals and lights alike, δY = ω × (Y − t) + τ, which leaves I unchanged but for
    the view direction — its rotation about the camera changes nothing and its translation
    τ' = τ − ω × t acts as the camera moved by −τ' — so ∂g'/∂X·δX of the corners' part (already
    in c) is replaced by ∂g'/∂X|_V·τ'."""
    N, gg, gX, w_lit, dn, src, pose = lit_point(shading, e, xi, eta, Xd, r, cam.t)
    N, v, c = sensitivities(mode, gg[:, None] * w + w_lit, Xd, xi, eta, ray, cam)
    return N, v, c + N[..., None] * gX[:, None, :], dn, src, pose


def lit_point(shading, e, xi, eta, Xd, r, t):
    """What the lighting of the point (ξ, η) of elements ``e`` (corners or control points Xd,
    camera frame; reference points r; the camera's translation t) adds to a sample's
    derivatives (:func:`lit_sensitivities`, :func:`fast_sensitivities`): the shape functions N at
    (ξ, η), ∂g'/∂g (n,), ∂g'/∂X (n, 3), ∂g'/∂(ξ, η) through X and Ñ (n, 2), dn (n, 4, 3):
    ∂g'/∂n_j, src (n, 4): the normals' rows of ``shading.D``, and the pose columns' term (n, 6)."""
    N, N_xi, N_eta = _shape_derivatives(xi, eta, Xd.shape[1])
    X = np.einsum("nk,nkd->nd", N, Xd)
    Nt, dNt, src, weights = shading.normals_at(e, xi, eta)
    gg, gX, gN, gV = shading.terms(r, X, Nt)
    w_lit = np.einsum("nd,ndl->nl", gX, _tangents(N_xi, N_eta, Xd)) + np.einsum("nd,ndl->nl", gN, dNt)
    t = np.asarray(t, np.float64)
    pose = np.hstack([np.cross(t, gX - gV) - np.cross(X, gX), gV - gX])
    return N, gg, gX, w_lit, weights[..., None] * gN[:, None, :], src, pose


def _total(parts: list, shape: tuple) -> sparse.csr_matrix:
    out = sum(parts[1:], parts[0]) if parts else sparse.csr_matrix(shape)
    out.sum_duplicates()
    return out
