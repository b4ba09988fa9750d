"""Inverse bilinear (Q4) mapping and ray / bilinear-patch intersection, numpy float64.

Mirrored function for function in ``shaders/bilinear.glsl``. Corners follow the FE order
0:(ξ,η)=(−1,−1), 1:(1,−1), 2:(1,1), 3:(−1,1); the forward map is x = Σ Φᵢ(ξ,η) pᵢ.
"""
from __future__ import annotations

import numpy as np

POLISH_RANGE = 1.5  # closed-form roots farther out than this are rejected unpolished
INSIDE_TOL = 1e-9  # |ξ|, |η| ≤ 1 + INSIDE_TOL counts as inside (pixels exactly on an edge)


def shape_functions(xi, eta):
    """Q4 shape functions (..., 4) in FE corner order."""
    xi, eta = np.broadcast_arrays(np.asarray(xi, dtype=np.float64), np.asarray(eta, dtype=np.float64))
    return 0.25 * np.stack([(1 - xi) * (1 - eta), (1 + xi) * (1 - eta),
                            (1 + xi) * (1 + eta), (1 - xi) * (1 + eta)], axis=-1)


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


def intersect_ray_patch(P, xn):
    """Nearest intersection of the camera rays through normalized image points xn (..., 2)
    (the ray from the origin along (x, y, 1)) with bilinear patches P (..., 4, 3) (camera
    frame, mm).

    A point X lies on the ray iff X − x·Z = 0 and Y − y·Z = 0: two planes through the ray.
    Evaluated at the corners they turn the intersection into a 2-D inverse bilinear problem
    with target (0, 0). Returns (ξ, η, depth Z, ok); ok needs a root inside the element in
    front of the camera.
    """
    p2 = P[..., :2] - xn[..., None, :] * P[..., 2:3]
    xi, eta, ok = invert_closed(p2, np.zeros(p2.shape[:-2] + (2,)))
    Z = bilinear(P[None, ..., 2:3], xi, eta)[..., 0]        # (2, ...)
    ok = ok & inside(xi, eta) & (Z > 0)
    first = np.where(ok[0] & (~ok[1] | (Z[0] <= Z[1])), 0, 1)
    pick = lambda a: np.take_along_axis(a, first[None], 0)[0]  # noqa: E731
    return pick(xi), pick(eta), pick(Z), pick(ok)
