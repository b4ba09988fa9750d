"""Bounds of GL's float32 exact build against the float64 oracle: precision = "fp32" in mode
exact on a driver with float64 (glsim.backends.gl.plan: CAMERA_LOCAL, REF_LOCAL — the element
records and the rays made in float64, each sample's work in float32 relative to its element's
centre; PIXEL_TIES through a pinhole). First order in u = 2^-24 under GLSL 4.50's rules: +, −
and × within u of the exact result (a contraction into a fused multiply-add rounds once, not
twice: within the same bound; the edge functions are `precise`), a stored float64 value within
u. Each quantity is carried as its value and a bound of its error (:class:`_F`) through the
shaders' operations in their order, each rounding within u of its exact result; where only a
bound of an operand's magnitude is known (a sample's ray or pixel anywhere in the image), a
sum's rounding within u(|a| + |b|).

- :func:`edge_px`: how far (px) from an element edge a sample may be given to the other side
  than the oracle's float64 decision: the edge function E = (x, y, 1)·(Pᵢ × (Pⱼ − Pᵢ))
  (ties.glsl's edge_functions_ray_ordered on the rounded camera-frame corners and the
  sample's float32 ray; through a pinhole pinhole_corners' K·P and the exact pixel point) —
  the corners' rounding taken as the displacement of the edge's ends in the image, the
  arithmetic on them over |∇E|. Its (ξ, η), whose float32 error is far smaller, only chooses
  where the edge function is asked (NEAR_TOL, 1e-3).
- :func:`mapping_px`: per pixel, the reference point's error: the camera-side problem's corners
  p = (D.xy − x D.z) − C.z d (sample_map.glsl's projected_corners) and the residual Σ Nᵢ pᵢ at the
  solution, through the inverse of its Jacobian (the last Newton steps leave (ξ, η) where the
  float32 residual vanishes, plus the update's own rounding), then through ∂ref/∂(ξ, η); and
  REF_LOCAL's own arithmetic (exact_reference: the offset from the centre's pixel, kept as
  hi + lo, the truth the exact sum of both). Assumes the two Newton polishes converged (the
  closed-form root's float32 error well below the element), as for any element the tie rule
  lets through.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from glsim.check import closed_forms, oracle_maps
from glsim.check.closed_forms import FLOAT32_ROUNDOFF as U

NEAR_TOL = 1e-3    # bilinear.glsl's float32 NEAR_TOL (|ξ|, |η| within it of 1: the edge function decides)


class _F(NamedTuple):
    """A float32 quantity: its exact value ``v`` and a bound ``e`` of the computed one's error."""
    v: np.ndarray
    e: np.ndarray


def _stored(x) -> _F:
    """A float64 value stored as float32 (a uniform, a record): within u|x|."""
    x = np.asarray(x, np.float64)
    return _F(x, U * np.abs(x))


def _exact(x) -> _F:
    x = np.asarray(x, np.float64)
    return _F(x, np.zeros_like(x))


def _add(a: _F, b: _F) -> _F:
    v = a.v + b.v
    return _F(v, a.e + b.e + U * np.abs(v))


def _sub(a: _F, b: _F) -> _F:
    v = a.v - b.v
    return _F(v, a.e + b.e + U * np.abs(v))


def _add_magnitudes(a: _F, b: _F) -> _F:
    """A sum whose operands are known by their magnitudes only (``v`` a bound of |value|): its
    rounding bounded by u(|a| + |b|)."""
    return _F(a.v + b.v, a.e + b.e + U * (a.v + b.v))


def _mul(a: _F, b: _F) -> _F:
    v = a.v * b.v
    return _F(v, np.abs(a.v) * b.e + np.abs(b.v) * a.e + U * np.abs(v))


def _div(a: _F, b: _F) -> _F:
    """GLSL's float division: within 2.5 ULP (5u) of the quotient of the computed operands."""
    v = a.v / b.v
    return _F(v, (a.e + np.abs(v) * b.e) / np.abs(b.v) + 5 * U * np.abs(v))


def _comp(P: np.ndarray, k: int, stored: bool = True) -> _F:
    return _stored(P[..., k]) if stored else _exact(P[..., k])


def _edge_function(A, B, x: _F, y: _F) -> tuple[_F, np.ndarray]:
    """E = (x·mx + y·my) + mz with m = A × (B − A) (ties.glsl's float32
    edge_functions_ray_ordered, `precise`; A the edge's first corner in node order), A, B as
    (3,) tuples of _F; returns E and |(mx, my)| (its gradient in (x, y)), exact."""
    d = [_sub(B[k], A[k]) for k in range(3)]
    mx = _sub(_mul(A[1], d[2]), _mul(A[2], d[1]))
    my = _sub(_mul(A[2], d[0]), _mul(A[0], d[2]))
    mz = _sub(_mul(A[0], d[1]), _mul(A[1], d[0]))
    ax, ay, az = (_F(np.abs(t.v), t.e) for t in (_mul(x, mx), _mul(y, my), mz))   # x, y: bounds of |x|, |y|
    E = _add_magnitudes(_add_magnitudes(ax, ay), az)
    return E, np.hypot(mx.v, my.v)


def edge_px(cam, Pa: np.ndarray, Pb: np.ndarray) -> np.ndarray:
    """Per edge a → b (camera-frame ends (K, 3), mm, float64; a the lower node index), the
    distance (px) within which a sample may be decided the other way (module text): what the
    float32 corners' own rounding moves the edge — its ends, each by its displacement in the
    image (through a pinhole: K·P with the intrinsics stored as float32, the products and sums
    rounded; else P rounded, and the sample's ray rounded to its float32 high half) — plus the
    edge function's arithmetic on those float32 corners over |∇E|: through a pinhole
    (PIXEL_TIES) at the exact pixel point (|u| ≤ W, |v| ≤ H), in px; under distortion at the
    ray (|x|, |y| at most the image's largest ray, glsim.imaging.view.ray_radius), in normalized coordinates times
    the largest ‖∂uv/∂xn‖ along the edge (fx, fy and the distortion's Jacobian at 9 points of
    its image). An edge with an end not in front of the camera (z ≤ 0, its image a half-line)
    takes the first-order bound of E with the corners' rounding in it, componentwise."""
    pinhole = not np.any(cam.distortion.coeffs)
    if pinhole:
        fx, fy, skew, cx, cy = (_stored(v) for v in cam.intrinsics)

        def corners(P):
            X, Y, Z = (_comp(P, k) for k in range(3))
            return (_add(_add(_mul(fx, X), _mul(skew, Y)), _mul(cx, Z)), _add(_mul(fy, Y), _mul(cy, Z)), Z)

        A, B = corners(Pa), corners(Pb)
        W, H = cam.size
        u, v = _exact(float(W)), _exact(float(H))
        whole, grad = _edge_function(A, B, u, v)
        E, _ = _edge_function(*(tuple(_exact(c.v) for c in X) for X in (A, B)), u, v)
        with np.errstate(divide="ignore", invalid="ignore"):
            moved = np.maximum(_end_px(A), _end_px(B))
            arith = np.where(np.minimum(A[2].v, B[2].v) > 0, moved + E.e / grad, whole.e / grad)
            return np.where(grad > 0, arith, np.inf)
    from glsim.imaging.view import ray_radius

    r = ray_radius(cam)   # |x|, |y| ≤ |xn| ≤ r for every sample's ray
    x = y = _exact(r)
    whole, grad = _edge_function(*(tuple(_comp(P, k) for k in range(3)) for P in (Pa, Pb)), _stored(r), _stored(r))
    E, _ = _edge_function(*(tuple(_comp(P, k, stored=False) for k in range(3)) for P in (Pa, Pb)), x, y)
    t = np.linspace(0.0, 1.0, 9)[:, None, None]
    P = Pa[None] * (1 - t) + Pb[None] * t                       # (9, K, 3)
    front = P[..., 2] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        xn = np.where(front[..., None], P[..., :2] / P[..., 2:], 0.0)
        gain = np.maximum(np.where(front, _gain(cam, xn), 0.0).max(axis=0), _gain(cam, np.zeros(2)))
        ends = [tuple(_comp(Q, k) for k in range(3)) for Q in (Pa, Pb)]
        moved = np.maximum(*(_end_px(Q) for Q in ends)) + U * r   # + the ray's rounding
        arith = np.where(np.minimum(Pa[:, 2], Pb[:, 2]) > 0, moved + E.e / grad, whole.e / grad)
        return np.where(grad > 0, arith * gain, np.inf)


def _end_px(A) -> np.ndarray:
    """How far its rounding moves the image (A.x/A.z, A.y/A.z) of a homogeneous point A (a tuple
    of three _F): (|δA.xy| + |A.xy/A.z|·δA.z)/A.z, first order (the units of A.xy/A.z)."""
    z = np.abs(A[2].v)
    return np.hypot(A[0].e + np.abs(A[0].v) / z * A[2].e, A[1].e + np.abs(A[1].v) / z * A[2].e) / z


def _gain(cam, xn: np.ndarray) -> np.ndarray:
    """‖∂uv/∂xn‖₂ at undistorted normalized points xn (..., 2): K's 2 × 2 part times the
    distortion's Jacobian."""
    from glsim.scene.camera import distort_jacobian

    K = np.array([[cam.fx, cam.skew], [0.0, cam.fy]])
    return np.linalg.norm(K @ distort_jacobian(xn, cam.distortion.coeffs), ord=2, axis=(-2, -1))


def mapping_px(view_corners: np.ndarray, ref_corners: np.ndarray, ref_intrinsics, e: np.ndarray,
               xi: np.ndarray, eta: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """Per covered pixel (element ``e``, the oracle's ``xi``, ``eta`` and ray ``xn`` (n, 2)), the
    bound (px) of the float32 exact build's reference point (its truth) against the oracle's:
    ``view_corners`` (M, 4, 3) the elements' corners in the view camera's frame and
    ``ref_corners`` (M, 4, 3) in the (pinhole) reference camera's, mm, float64; intrinsics of
    the reference camera (fx, fy, skew, cx, cy). Module text; an element whose centre is not in
    front of the camera takes projected_corners' other branch, P.xy − x P.z on the rounded
    corners."""
    dxe = solve_error(view_corners[e], xi, eta, xn)
    R = ref_corners[e]
    Cr = R.mean(axis=1)
    fx, fy, skew, cx, cy = (float(v) for v in ref_intrinsics)
    Ns = _shape32(xi, eta)
    # REF_LOCAL: d = Σ Nᵢ Dᵢ, dxn = (d.xy C.z − C.xy d.z) / (C.z (C.z + d.z)), duv = K dxn, and the
    # truth hi + (lo + duv) (Fast2Sum keeps the sum's rounding): the errors of lo + duv
    d3 = []
    for k in range(3):
        t = [_mul(Ns[i], _stored(R[:, i, k] - Cr[:, k])) for i in range(4)]
        d3.append(_add(_add(_add(t[0], t[1]), t[2]), t[3]))
    Cs = [_stored(Cr[:, k]) for k in range(3)]
    den = _mul(Cs[2], _add(Cs[2], d3[2]))
    dxn = [_div(_sub(_mul(d3[k], Cs[2]), _mul(Cs[k], d3[2])), den) for k in range(2)]
    duv = [_add(_mul(_stored(fx), dxn[0]), _mul(_stored(skew), dxn[1])), _mul(_stored(fy), dxn[1])]
    uv_c = np.stack([fx * (Cr[:, 0] / Cr[:, 2]) + skew * (Cr[:, 1] / Cr[:, 2]) + cx, fy * (Cr[:, 1] / Cr[:, 2]) + cy], -1)
    lo = uv_c - uv_c.astype(np.float32).astype(np.float64)
    arith = np.hypot(*(_add(_stored(lo[:, k]), duv[k]).e for k in range(2)))
    gain = np.linalg.norm(_ref_jacobian(R, fx, fy, skew, xi, eta), ord=2, axis=(-2, -1))
    return arith + gain * dxe


def _shape32(xi, eta) -> list[_F]:
    """The four 0.25 (1 ± ξ)(1 ± η) in float32 (three roundings each)."""
    from glsim.scene import bilinear as bl

    N = bl.shape_functions(xi, eta)
    return [_F(N[:, i], 3 * U * np.abs(N[:, i])) for i in range(4)]


def solve_error(P: np.ndarray, xi: np.ndarray, eta: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """The bound of |Δ(ξ, η)| (2-norm) of the float32 build's camera-side solution for rays
    ``xn`` (n, 2) in elements with camera-frame corners ``P`` (n, 4, 3), mm, at the float64
    solution (``xi``, ``eta``): the float32 corners p (CAMERA_LOCAL where the centre lies in
    front, else P.xy − x P.z on the rounded corners) and the residual Σ Nᵢ pᵢ's rounding, through
    the smallest singular value of its Jacobian, plus the last update's rounding."""
    C = P.mean(axis=1)
    local = C[:, 2] > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = np.where(local[:, None], C[:, :2] / C[:, 2:], 0.0)
    c_hi = xc.astype(np.float32).astype(np.float64)
    x_hi = xn.astype(np.float32).astype(np.float64)
    x_lo = xn - x_hi
    Ns = _shape32(xi, eta)
    f_err = np.zeros((len(P), 2))
    for k in range(2):
        # CAMERA_LOCAL: d = (x_hi − C_hi) + (x_lo − C_lo); p = (D.xy − x_hi D.z) − C.z d (+ x_lo D.z dropped)
        d = _add(_sub(_exact(x_hi[:, k]), _exact(c_hi[:, k])), _sub(_stored(x_lo[:, k]), _stored(xc[:, k] - c_hi[:, k])))
        cz = _stored(np.where(local, C[:, 2], 0.0))
        terms = []
        for i in range(4):
            D = P[:, i] - C
            near = _sub(_sub(_stored(D[:, k]), _mul(_exact(x_hi[:, k]), _stored(D[:, 2]))), _mul(cz, d))
            far = _sub(_stored(P[:, i, k]), _mul(_exact(x_hi[:, k]), _stored(P[:, i, 2])))
            err = np.where(local, near.e + np.abs(x_lo[:, k] * D[:, 2]), far.e + np.abs(x_lo[:, k] * P[:, i, 2]))
            p = P[:, i, k] - xn[:, k] * P[:, i, 2]
            terms.append(_mul(Ns[i], _F(p, err)))
        f_err[:, k] = _add(_add(_add(terms[0], terms[1]), terms[2]), terms[3]).e
    # (ξ, η)'s error: the residual's through J⁻¹ (J of the float64 p), and the update's rounding
    a, b = _jacobian(P[..., :2] - xn[:, None, :] * P[..., 2:], xi, eta)
    sigma = np.linalg.svd(np.stack([a, b], -1), compute_uv=False)[:, -1]
    with np.errstate(divide="ignore"):
        return np.linalg.norm(f_err, axis=1) / sigma + np.sqrt(2) * U * (1 + NEAR_TOL)


def renderer_ties(renderer, cam: int, step: int, spp: int = 1) -> np.ndarray:
    """:func:`glsim.check.oracle_maps.renderer_ties` of a GL renderer's float32 exact build:
    each edge within its :func:`edge_px` (+ float64's); on a driver with float64 (CAMERA_LOCAL)
    only."""
    if not renderer.backend.capabilities.float64:
        raise ValueError("exact32.renderer_ties: derived for the build with float64 records (CAMERA_LOCAL) only")
    camera = renderer.scene.cameras[cam]
    return oracle_maps.renderer_ties(renderer, "exact", cam, step, spp,
                                radius=lambda Pa, Pb: edge_px(camera, Pa, Pb) + closed_forms.FLOAT64)


def renderer_mapping(renderer, truth, cam: int, step: int) -> np.ndarray:
    """Per pixel (H, W): :func:`mapping_px` for a GL renderer's float32 exact build of camera
    ``cam`` at ``step`` at 1 spp, from the oracle's ``truth`` of that view (its element, ξ, η and
    each pixel centre's ray, as rays.frag makes them in float64); 0 off its mask. Refuses what
    the build does without the float64 records (a driver without float64), a distorted
    reference camera (no REF_LOCAL: its float32 projection is not derived here) and quadratic
    meshes."""
    from glsim.scene.camera import pixel_to_normalized, undistort
    from glsim.imaging.view import make_view

    ref = renderer.reference.camera
    if not renderer.backend.capabilities.float64 or np.any(ref.distortion.coeffs) or renderer.mesh.is_quadratic:
        raise ValueError("exact32.renderer_mapping: derived for CAMERA_LOCAL and REF_LOCAL only (a driver with "
                         "float64, a pinhole reference camera, linear elements)")
    mesh, camera = renderer.mesh, renderer.scene.cameras[cam]
    view = make_view(camera, ref, mesh.nodes, mesh.deformed(step), mesh.quads, warn=False)
    v, u = np.nonzero(truth.mask)
    xn, _ = undistort(pixel_to_normalized(np.stack([u, v], -1).astype(np.float64), camera.intrinsics),
                      camera.distortion.coeffs)
    out = np.zeros(truth.mask.shape)
    out[v, u] = mapping_px(view.Xd, view.Xr, ref.intrinsics, truth.element[v, u], truth.xi[v, u], truth.eta[v, u], xn)
    return out


def _jacobian(p: np.ndarray, xi: np.ndarray, eta: np.ndarray):
    """∂(Σ Nᵢ pᵢ)/∂ξ and /∂η for corners p (n, 4, k)."""
    from glsim.scene import bilinear as bl

    return (np.einsum("ni,nik->nk", dN, p) for dN in bl.shape_derivatives(xi, eta))


def _ref_jacobian(R: np.ndarray, fx: float, fy: float, skew: float, xi: np.ndarray, eta: np.ndarray) -> np.ndarray:
    """∂uv/∂(ξ, η) (n, 2, 2) of the pinhole projection of the bilinear point on corners R."""
    from glsim.scene import bilinear as bl

    X = np.einsum("ni,nik->nk", bl.shape_functions(xi, eta), R)
    a, b = _jacobian(R, xi, eta)
    K = np.array([[fx, skew], [0.0, fy]])
    out = np.empty((len(X), 2, 2))
    for j, dX in enumerate((a, b)):
        dxn = (dX[:, :2] * X[:, 2:] - X[:, :2] * dX[:, 2:]) / X[:, 2:] ** 2
        out[:, :, j] = dxn @ K.T
    return out
