"""Inverse bilinear (Q4) mapping and ray / bilinear-patch intersection, numpy float64.

Mirrored function for function in ``shaders/bilinear.glsl`` (the tie rule: ``ties.glsl``).
Corners follow the FE order 0:(ξ,η)=(−1,−1), 1:(1,−1), 2:(1,1), 3:(−1,1); the forward map is
x = Σ Φᵢ(ξ,η) pᵢ.

Coverage (which element owns a sample) follows one tie rule, the same here and in GLSL: a
sample whose (ξ, η) lies within ``NEAR_TOL`` of an element edge is decided by that edge's
*edge function* E (in pixel space for ``q4``, in ray space — the plane through the camera
centre and the edge — for ``exact``), which is computed so that two elements sharing an edge
get exactly opposite values. The sample is owned where the element lies on its positive side
(s·E > 0, s the element's local orientation); where E is exactly 0 it is owned by the element
that contains the sample moved by an infinitesimal step to the right (+x), or, on an edge
parallel to x, down (+y): the top-left rule of rasterizers, written as a symbolic
perturbation. So every sample inside a conforming mesh belongs to exactly one element, and an
axis-aligned outline [u0, u1] × [v0, v1] covers u0 ≤ u < u1, v0 ≤ v < v1. See
docs/hard_cases.md.
"""
from __future__ import annotations

import numpy as np

POLISH_RANGE = 1.5  # closed-form roots farther out than this are rejected unpolished
INSIDE_TOL = 1e-9  # |ξ|, |η| ≤ 1 + INSIDE_TOL counts as inside (pixels exactly on an edge)
NEAR_TOL = 1e-6  # |ξ|, |η| within this of 1: the edge function decides (tie rule above)
EDGES = ((0, 1), (1, 2), (2, 3), (3, 0))  # edge k: η = −1, ξ = +1, η = +1, ξ = −1


def shape_functions(xi, eta):
    """Q4 shape functions (..., 4) in FE corner order."""
    xi, eta = np.broadcast_arrays(np.asarray(xi, dtype=np.float64), np.asarray(eta, dtype=np.float64))
    return 0.25 * np.stack([(1 - xi) * (1 - eta), (1 + xi) * (1 - eta),
                            (1 + xi) * (1 + eta), (1 - xi) * (1 + eta)], axis=-1)


def shape_derivatives(xi, eta):
    """(∂N/∂ξ, ∂N/∂η), each (..., 4), of :func:`shape_functions`."""
    xi, eta = np.broadcast_arrays(np.asarray(xi, dtype=np.float64), np.asarray(eta, dtype=np.float64))
    return (0.25 * np.stack([-(1 - eta), 1 - eta, 1 + eta, -(1 + eta)], -1),
            0.25 * np.stack([-(1 - xi), -(1 + xi), 1 + xi, 1 - xi], -1))


def bilinear(p, xi, eta):
    """Forward map: corners p (..., 4, D) at (ξ, η) → (..., D)."""
    return np.einsum("...i,...id->...d", shape_functions(xi, eta), np.asarray(p, dtype=np.float64))


def _residual_jacobian(p, xi, eta, q):
    f = bilinear(p, xi, eta) - q
    dxi = 0.25 * ((p[..., 1, :] - p[..., 0, :]) * (1 - eta)[..., None]
                  + (p[..., 2, :] - p[..., 3, :]) * (1 + eta)[..., None])
    deta = 0.25 * ((p[..., 3, :] - p[..., 0, :]) * (1 - xi)[..., None]
                   + (p[..., 2, :] - p[..., 1, :]) * (1 + xi)[..., None])
    return f, dxi, deta


def newton_step(p, xi, eta, q):
    """One Gauss–Newton update (paper eqs. 5–9) of (ξ, η) for 2-D corners; returns (Δξ, Δη, det)."""
    f, a, b = _residual_jacobian(p, xi, eta, q)
    det = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    safe = np.where(det == 0, 1.0, det)
    dxi = -(b[..., 1] * f[..., 0] - b[..., 0] * f[..., 1]) / safe
    deta = -(a[..., 0] * f[..., 1] - a[..., 1] * f[..., 0]) / safe
    return np.where(det == 0, 0.0, dxi), np.where(det == 0, 0.0, deta), det


def invert_newton(p, q, tol=1e-12, max_iter=50):
    """The paper's inverse mapping: Gauss–Newton from (0, 0) until |Δ| ≤ tol.

    Returns (ξ, η, ok); ok is False where it did not converge within ``max_iter`` or the
    Jacobian is singular. ξ, η are always finite. Works relative to corner 0 (as the shader,
    where that keeps float32 residuals at the element's scale).
    """
    o = p[..., :1, :]
    p, q = p - o, q - o[..., 0, :]
    shape = np.asarray(q).shape[:-1]
    xi = np.zeros(shape)
    eta = np.zeros(shape)
    done = np.zeros(shape, dtype=bool)
    for _ in range(max_iter):
        dxi, deta, det = newton_step(p, xi, eta, q)
        dxi = np.clip(dxi, -4, 4)
        deta = np.clip(deta, -4, 4)
        xi = np.where(done, xi, xi + dxi)
        eta = np.where(done, eta, eta + deta)
        done |= (np.maximum(np.abs(dxi), np.abs(deta)) <= tol) & (det != 0)
        if done.all():
            break
    return xi, eta, done


def _cross(a, b):
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def invert_closed(p, q):
    """Both roots of the inverse bilinear map in closed form, each polished by two Newton steps.

    Returns (xi, eta, ok) of shape (2, ...): ok marks real roots. With the parameters
    s = (ξ+1)/2, t = (η+1)/2 the map is q = p0 + s e + t f + s t g, and eliminating s
    gives A t² + B t + C = 0, solved with the cancellation-free quadratic formula.
    """
    p0, p1, p2, p3 = (p[..., i, :] for i in range(4))
    e, f, g, h = p1 - p0, p3 - p0, p0 - p1 + p2 - p3, q - p0
    A = _cross(f, g)
    B = _cross(f, e) - _cross(h, g)
    C = -_cross(h, e)
    scale = np.abs(B) + np.abs(C) + np.abs(A)
    linear = np.abs(A) <= 1e-12 * np.where(scale == 0, 1.0, scale)
    disc = B * B - 4 * A * C
    real = disc >= 0
    sq = np.sqrt(np.maximum(disc, 0.0))
    Q = -0.5 * (B + np.where(B >= 0, sq, -sq))
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = np.where(linear, -C / np.where(B == 0, 1.0, B), Q / np.where(A == 0, 1.0, A))
        t2 = np.where(Q == 0, t1, C / np.where(Q == 0, 1.0, Q))
    ok1 = np.where(linear, B != 0, real)
    ok2 = ok1 & ~linear
    xs, es, oks = [], [], []
    for t, ok in ((t1, ok1), (t2, ok2)):
        t = np.where(ok & np.isfinite(t), t, 0.5)
        den = e + t[..., None] * g
        dd = np.einsum("...d,...d->...", den, den)
        s = np.einsum("...d,...d->...", h - t[..., None] * f, den) / np.where(dd == 0, 1.0, dd)
        xi, eta = 2 * s - 1, 2 * t - 1
        near = (np.abs(xi) <= POLISH_RANGE) & (np.abs(eta) <= POLISH_RANGE)
        for _ in range(2):
            dxi, deta, _ = newton_step(p, xi, eta, q)
            xi, eta = xi + dxi, eta + deta
        good = ok & near & (dd != 0) & np.isfinite(xi) & np.isfinite(eta)
        xs.append(np.where(good, xi, 0.0))
        es.append(np.where(good, eta, 0.0))
        oks.append(good)
    return np.stack(xs), np.stack(es), np.stack(oks)


def inside(xi, eta, tol=INSIDE_TOL):
    return (np.abs(xi) <= 1 + tol) & (np.abs(eta) <= 1 + tol)


def edge_functions_2d(p, q, edges=EDGES):
    """Edge functions of the 2-D quads p (..., 4, 2) at points q (..., 2): E (..., K), positive
    left of edge i → j, and their gradients m (..., K, 2), for the K ``edges`` (i, j). E =
    cross(pᵢ − q, pⱼ − q) is exactly antisymmetric in (i, j), so two elements sharing an edge
    get exactly opposite values."""
    q = np.asarray(q, dtype=np.float64)[..., None, :]
    i, j = [k for k, _ in edges], [k for _, k in edges]
    a, b = p[..., i, :] - q, p[..., j, :] - q
    E = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    m = np.stack([p[..., i, 1] - p[..., j, 1], p[..., j, 0] - p[..., i, 0]], -1)
    return E, m


def edge_functions_ray(P, xn):
    """Edge functions of patches P (..., 4, 3) (camera frame) for the rays (xn, 1), xn (..., 2):
    E = (xn, 1) · (Pᵢ × Pⱼ), the side of the plane through the camera centre and edge i → j
    (exactly antisymmetric in (i, j)), and the gradients m (..., 4, 2) of E in xn. With P
    replaced by :func:`pinhole_corners` and xn by pixel points (u, v), the same in pixel space."""
    i, j = [k for k, _ in EDGES], [k for _, k in EDGES]
    A, B = P[..., i, :], P[..., j, :]
    mx = A[..., 1] * B[..., 2] - A[..., 2] * B[..., 1]
    my = A[..., 2] * B[..., 0] - A[..., 0] * B[..., 2]
    mz = A[..., 0] * B[..., 1] - A[..., 1] * B[..., 0]
    x, y = xn[..., 0:1], xn[..., 1:2]
    return (x * mx + y * my) + mz, np.stack([mx, my], -1)


def pinhole_corners(P, intr):
    """K·P for camera-frame points P (..., 3) and pinhole intrinsics (fx, fy, skew, cx, cy):
    (fx X + skew Y + cx Z, fy Y + cy Z, Z). Then (u, v, 1) · (Aᵢ × Aⱼ) = fx fy · E of
    :func:`edge_functions_ray`: the same side, measured from the sample's pixel point, which is
    exact, instead of its rounded normalized ray — so an outline through pixel centres is an
    exact tie wherever K·P is exact (whole or dyadic set-ups) and the tie rule decides."""
    fx, fy, skew, cx, cy = (float(v) for v in intr)
    X, Y, Z = P[..., 0], P[..., 1], P[..., 2]
    return np.stack([(fx * X + skew * Y) + cx * Z, fy * Y + cy * Z, Z], -1)


def edge_owns(E, m, s):
    """The tie rule for one edge: the element (local orientation s = ±1, broadcast with E) owns
    the sample if s·E > 0, or if s·E = 0 and its inward normal s·m points to +x, or, with a
    zero x component, to +y. A collapsed edge (m = 0) decides nothing."""
    s = np.asarray(s, dtype=np.float64)
    sE, smx, smy = s * E, s * m[..., 0], s * m[..., 1]
    collapsed = (m[..., 0] == 0) & (m[..., 1] == 0)
    return collapsed | (sE > 0) | ((sE == 0) & ((smx > 0) | ((smx == 0) & (smy > 0))))


# mode fast's two triangles per quad (corner indices), tried in this order
FAST_TRIANGLES = ((0, 1, 2), (0, 2, 3))


def triangle_barycentric(p, q, tri, taken):
    """Screen-space barycentric coordinates λ (n, 3) of points q (n, 2) in triangle ``tri`` of
    quads p (n, 4, 2), and whether the triangle owns q under the tie rule on its edge functions
    (as GL's rasterizer, which however snaps the vertices to its sub-pixel grid first), unless
    ``taken`` (n,) by an earlier triangle."""
    a, b, c = (p[:, k] for k in tri)
    den = _cross(b - a, c - a)
    safe = np.where(den == 0, 1.0, den)
    l1 = _cross(q - a, c - a) / safe
    l2 = _cross(b - a, q - a) / safe
    E, m = edge_functions_2d(p, q, edges=tuple(zip(tri, tri[1:] + tri[:1])))
    hit = (den != 0) & ~taken & edge_owns(E, m, np.sign(den)[:, None]).all(-1)
    return np.stack([1 - l1 - l2, l1, l2], -1), hit


def owned(xi, eta, E, m, s, tol=NEAR_TOL):
    """Coverage under the tie rule: (ξ, η) within [−1 − tol, 1 + tol]², and for each edge the
    sample is within ``tol`` of, :func:`edge_owns`. E, m: (..., 4), (..., 4, 2); s (...,)."""
    ok = (np.abs(xi) <= 1 + tol) & (np.abs(eta) <= 1 + tol)
    near = np.stack([eta <= -1 + tol, xi >= 1 - tol, eta >= 1 - tol, xi <= -1 + tol], -1)
    own = edge_owns(E, m, np.asarray(s, dtype=np.float64)[..., None])
    return ok & (~near | own).all(-1)


def orientation_2d(p, xi, eta):
    """Local orientation (sign of det J, ±1) of the 2-D map at (ξ, η); where det J = 0 (a
    collapsed corner) the sign of the element's signed area; 0 for zero-area elements."""
    _, a, b = _residual_jacobian(p, xi, eta, 0.0)
    det = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    area = _cross(p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]) + \
        _cross(p[..., 2, :] - p[..., 0, :], p[..., 3, :] - p[..., 0, :])
    return np.where(det != 0, np.sign(det), np.sign(area))


def orientation_ray(P, xi, eta):
    """Local orientation of patch P seen from the camera centre: the sign of X · (X_ξ × X_η)
    at (ξ, η); where that is 0, the sign of the pyramid volume camera–quad; ±1 or 0."""
    X, a, b = _residual_jacobian(P, xi, eta, 0.0)
    local = np.einsum("...d,...d->...", X, np.cross(a, b))
    P0, P1, P2, P3 = (P[..., k, :] for k in range(4))
    vol = np.einsum("...d,...d->...", P0, np.cross(P1, P2) + np.cross(P2, P3))
    return np.where(local != 0, np.sign(local), np.sign(vol))


def intersect_ray_patch(P, xn, pixel=None):
    """Nearest intersection of the camera rays through normalized image points xn (..., 2)
    (the ray from the origin along (x, y, 1)) with bilinear patches P (..., 4, 3) (camera
    frame, mm).

    A point X lies on the ray iff X − x·Z = 0 and Y − y·Z = 0: two planes through the ray.
    Evaluated at the corners they turn the intersection into a 2-D inverse bilinear problem
    with target (0, 0). Returns (ξ, η, depth Z, ok); ok needs a root inside the element in
    front of the camera and owned under the tie rule (module docstring), decided in pixel space
    (:func:`pinhole_corners`) where ``pixel = (q, intr)`` gives the samples' pixel points q
    (..., 2) of a pinhole camera.
    """
    p2 = P[..., :2] - xn[..., None, :] * P[..., 2:3]
    xi, eta, ok = invert_closed(p2, np.zeros(p2.shape[:-2] + (2,)))
    Z = bilinear(P[None, ..., 2:3], xi, eta)[..., 0]        # (2, ...)
    ok = ok & (Z > 0) & inside(xi, eta, NEAR_TOL)
    near = ok & ((np.abs(xi) >= 1 - NEAR_TOL) | (np.abs(eta) >= 1 - NEAR_TOL))
    if near.any():  # the tie rule, only where it can matter (it costs more than the root)
        batch = np.broadcast_shapes(P.shape[:-2], xn.shape[:-1])
        P, xn = np.broadcast_to(P, batch + (4, 3)), np.broadcast_to(xn, batch + (2,))
        k, *rest = np.nonzero(near)
        Ps, xs, es = P[tuple(rest)], xi[near], eta[near]
        if pixel is None:
            E, m = edge_functions_ray(Ps, xn[tuple(rest)])
        else:
            q = np.broadcast_to(pixel[0], batch + (2,))
            E, m = edge_functions_ray(pinhole_corners(Ps, pixel[1]), q[tuple(rest)])
        ok[near] = owned(xs, es, E, m, orientation_ray(Ps, xs, es))
    first = np.where(ok[0] & (~ok[1] | (Z[0] <= Z[1])), 0, 1)
    pick = lambda a: np.take_along_axis(a, first[None], 0)[0]  # noqa: E731
    return pick(xi), pick(eta), pick(Z), pick(ok)
