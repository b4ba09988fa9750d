"""glsim.check.exact32's bounds against the float32 build's arithmetic replayed in numpy
float32 (each operation rounded once, in the shaders' order: ties.glsl's edge functions,
bilinear.glsl's Newton step, sample_map.glsl's projected_corners and exact_reference) on random elements: the
float32 results lie within the bounds, which are not vacuous: small, and within a factor of
100 (the edge functions) or 20 (the mapping) of the errors somewhere."""
import numpy as np
import pytest

from glsim.check import exact32
from glsim.scene import bilinear as bl
from glsim.scene.camera import Camera, Distortion

f32 = np.float32


def random_elements(rng, n, z=(300.0, 900.0), size=(1.0, 8.0)):
    """n random non-degenerate quads (n, 4, 3) in a camera frame, mm: a square of random size
    and tilt around a random point in front of the camera, corners jittered by 10 %."""
    c = np.column_stack([rng.uniform(-0.4, 0.4, (n, 2)), np.ones(n)]) * rng.uniform(*z, (n, 1))
    s = rng.uniform(*size, (n, 1, 1))
    sq = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)[None] * s / 2
    a, b = rng.uniform(-1.2, 1.2, (2, n))
    Ra = np.stack([np.stack([np.ones(n), np.zeros(n), np.zeros(n)], -1),
                   np.stack([np.zeros(n), np.cos(a), -np.sin(a)], -1), np.stack([np.zeros(n), np.sin(a), np.cos(a)], -1)], 1)
    Rb = np.stack([np.stack([np.cos(b), np.zeros(n), np.sin(b)], -1), np.stack([np.zeros(n), np.ones(n), np.zeros(n)], -1),
                   np.stack([-np.sin(b), np.zeros(n), np.cos(b)], -1)], 1)
    corners = np.einsum("nij,njk,nck->nci", Ra, Rb, sq) + s * rng.uniform(-0.1, 0.1, (n, 4, 3))
    return c[:, None] + corners


def edge_function32(A, B, x, y):
    """ties.glsl's float32 edge function, edge_functions_ray_ordered: A × (B − A) from the
    edge's first corner (`precise`: no fused multiply-add)."""
    A, B, x, y = (np.asarray(v, f32) for v in (A, B, x, y))
    d = B - A
    mx = A[:, 1] * d[:, 2] - A[:, 2] * d[:, 1]
    my = A[:, 2] * d[:, 0] - A[:, 0] * d[:, 2]
    mz = A[:, 0] * d[:, 1] - A[:, 1] * d[:, 0]
    return (x * mx + y * my) + mz


def edge_function64(A, B, x, y):
    m = np.cross(A, B)
    return x * m[:, 0] + y * m[:, 1] + m[:, 2], np.hypot(m[:, 0], m[:, 1])


@pytest.mark.parametrize("distortion", [Distortion(), Distortion(k1=-0.2, k2=0.05)], ids=["pinhole", "distorted"])
def test_edge_distance_bounds_the_float32_edge_function(distortion):
    """Samples near random edges: |E₃₂ − E|/|∇E| within edge_px (through a pinhole in pixel
    space on K·P at the exact pixel point; else at the ray's float32 high half, times the
    largest ‖∂uv/∂xn‖, here at least fx), which is a few 1e-3 px at most here."""
    rng = np.random.default_rng(3)
    cam = Camera(name="c", size=(1624, 1234), fx=3000.0, fy=3000.0, cx=812.0, cy=617.0, distortion=distortion)
    P = random_elements(rng, 4000)
    Pa, Pb = P[:, 0], P[:, 1]
    radius = exact32.edge_px(cam, Pa, Pb)
    t = rng.uniform(0, 1, (len(P), 1))
    X = Pa * (1 - t) + Pb * t                                           # a point on the edge
    xn = X[:, :2] / X[:, 2:]
    if not np.any(distortion.coeffs):
        K = np.array([[cam.fx, cam.skew, cam.cx], [0, cam.fy, cam.cy], [0, 0, 1]])
        uv = xn @ K[:2, :2].T + K[:2, 2]
        uv = np.round(uv * 4) / 4                                       # a sample point near it (exact in float32)
        Kf = K.astype(f32)

        def corners32(Q):
            Q = Q.astype(f32)
            return np.stack([(Kf[0, 0] * Q[:, 0] + Kf[0, 1] * Q[:, 1]) + Kf[0, 2] * Q[:, 2],
                             Kf[1, 1] * Q[:, 1] + Kf[1, 2] * Q[:, 2], Q[:, 2]], -1)
        E32 = edge_function32(corners32(Pa), corners32(Pb), uv[:, 0], uv[:, 1])
        E, grad = edge_function64(Pa @ K.T, Pb @ K.T, uv[:, 0], uv[:, 1])
        dist = np.abs(E32 - E) / grad
    else:
        x32 = xn.astype(f32)
        E32 = edge_function32(Pa, Pb, x32[:, 0], x32[:, 1])
        E, grad = edge_function64(Pa, Pb, xn[:, 0], xn[:, 1])
        dist = np.abs(E32 - E) / grad * cam.fx                        # ≥ fx·(xn distance): at most the bound
    assert (dist <= radius).all(), (dist / radius).max()
    # (the float32 edge function P x P' instead of P x (P' − P) erred by up to 0.13 px here)
    assert np.median(radius) < 0.01 and (dist > 0).mean() > 0.5
    assert (dist / radius).max() > 0.01                                 # the bound is not loose by orders


def newton32(p, xi, eta, steps=2):
    """bilinear.glsl's newton_step in float32 from (xi, eta), p (n, 4, 2) float32, q = 0."""
    x, y = xi.astype(f32), eta.astype(f32)
    q = f32(0.25)
    for _ in range(steps):
        N = [q * (1 - x) * (1 - y), q * (1 + x) * (1 - y), q * (1 + x) * (1 + y), q * (1 - x) * (1 + y)]
        F = ((N[0][:, None] * p[:, 0] + N[1][:, None] * p[:, 1]) + N[2][:, None] * p[:, 2]) + N[3][:, None] * p[:, 3]
        a = q * ((p[:, 1] - p[:, 0]) * (1 - y)[:, None] + (p[:, 2] - p[:, 3]) * (1 + y)[:, None])
        b = q * ((p[:, 3] - p[:, 0]) * (1 - x)[:, None] + (p[:, 2] - p[:, 1]) * (1 + x)[:, None])
        det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        inv = f32(1) / det
        x = x + -(b[:, 1] * F[:, 0] - b[:, 0] * F[:, 1]) * inv
        y = y + -(a[:, 0] * F[:, 1] - a[:, 1] * F[:, 0]) * inv
    return x.astype(float), y.astype(float)


def reference32(R, K, xi, eta):
    """sample_map.glsl's exact_reference with REF_LOCAL in float32, and the truth hi + lo."""
    C = R.mean(axis=1)
    D = (R - C[:, None]).astype(f32)
    x, y = xi.astype(f32), eta.astype(f32)
    q = f32(0.25)
    N = [q * (1 - x) * (1 - y), q * (1 + x) * (1 - y), q * (1 + x) * (1 + y), q * (1 - x) * (1 + y)]
    d = ((N[0][:, None] * D[:, 0] + N[1][:, None] * D[:, 1]) + N[2][:, None] * D[:, 2]) + N[3][:, None] * D[:, 3]
    Cf = C.astype(f32)
    zd = Cf[:, 2] + d[:, 2]
    dxn = (d[:, :2] * Cf[:, 2:] - Cf[:, :2] * d[:, 2:]) / (Cf[:, 2] * zd)[:, None]
    Kf = K.astype(f32)
    duv = np.stack([Kf[0, 0] * dxn[:, 0] + Kf[0, 1] * dxn[:, 1], Kf[1, 1] * dxn[:, 1]], -1)
    uv = C[:, :2] / C[:, 2:] @ K[:2, :2].T + K[:2, 2]
    hi = uv.astype(f32)
    lo = (uv - hi).astype(f32) + duv
    return hi.astype(float) + lo.astype(float)                       # Fast2Sum: exactly hi + (lo + duv)


def test_mapping_bounds_the_float32_camera_and_reference_arithmetic():
    """Random elements seen by a camera and a pinhole reference camera (both frames the same
    here), random (ξ, η) inside: the camera-side corners p relative to the centre and two
    Newton steps in float32 from a start 1e-3 off — (ξ, η) within solve_error —, then REF_LOCAL
    in float32 — the reference point within mapping_px of the float64 one; each within a factor
    20 of its bound somewhere."""
    rng = np.random.default_rng(5)
    n = 20000
    P = random_elements(rng, n)
    K = np.array([[3000.0, 0.3, 800.0], [0, 3000.0, 600.0], [0, 0, 1]])
    xi, eta = rng.uniform(-0.999, 0.999, (2, n))
    X = np.einsum("ni,nik->nk", bl.shape_functions(xi, eta), P)
    xn = X[:, :2] / X[:, 2:]
    # camera side: CAMERA_LOCAL's p in float32, Newton from a perturbed start
    C = P.mean(axis=1)
    xc = C[:, :2] / C[:, 2:]
    c_hi = xc.astype(f32)
    x_hi = xn.astype(f32)
    d = (x_hi - c_hi) + ((xn - x_hi).astype(f32) - (xc - c_hi).astype(f32))
    D = (P - C[:, None]).astype(f32)
    p = (D[..., :2] - x_hi[:, None] * D[..., 2:]) - C[:, 2].astype(f32)[:, None, None] * d[:, None]
    x32, y32 = newton32(p, xi + rng.uniform(-1e-3, 1e-3, n), eta + rng.uniform(-1e-3, 1e-3, n))
    dxe = np.hypot(x32 - xi, y32 - eta)
    solve = exact32.solve_error(P, xi, eta, xn)
    assert (dxe <= solve).all() and (dxe / solve).max() > 0.05, (dxe / solve).max()
    got = reference32(P, K, x32, y32)
    want = np.einsum("ni,nik->nk", bl.shape_functions(xi, eta), P)
    want = want[:, :2] / want[:, 2:] @ K[:2, :2].T + K[:2, 2]
    err = np.linalg.norm(got - want, axis=1)
    intr = (K[0, 0], K[1, 1], K[0, 1], K[0, 2], K[1, 2])
    bound = exact32.mapping_px(P, P, intr, np.arange(n), xi, eta, xn)
    assert (err <= bound).all(), (err / bound).max()
    assert np.median(bound) < 1e-3 and (err / bound).max() > 0.05
