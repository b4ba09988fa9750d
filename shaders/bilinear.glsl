// Inverse bilinear (Q4) mapping and ray / bilinear-patch intersection: the GLSL twin of
// glsim/scene/bilinear.py (same names and steps). Corners in FE order 0:(-1,-1) 1:(1,-1) 2:(1,1) 3:(-1,1).
#ifdef FP64
#define NEWTON_TOL 1e-12
#define INSIDE_TOL 1e-9
#else
#define NEWTON_TOL 1e-6
#define INSIDE_TOL 1e-5
#endif
// q4 coverage comes from rasterizing float32 vertex positions; a fragment the rasterizer gives
// to this element may map a hair outside it (|xi| up to ~1 + 1e-5). Accepting it avoids holes
// on shared edges; the bilinear field is continuous there, so the extrapolation is harmless.
#define RASTER_INSIDE_TOL 1e-4
#define NEWTON_MAX_ITER 20
#define POLISH_RANGE 1.5  // closed-form roots beyond |xi|, |eta| > 1.5 are not polished

real cross2(real2 a, real2 b) { return a.x * b.y - a.y * b.x; }

real4 shape_functions(real xi, real eta) {
    return 0.25 * real4((1.0 - xi) * (1.0 - eta), (1.0 + xi) * (1.0 - eta),
                        (1.0 + xi) * (1.0 + eta), (1.0 - xi) * (1.0 + eta));
}

real2 bilinear2(real2 p[4], real xi, real eta) {
    real4 N = shape_functions(xi, eta);
    return N.x * p[0] + N.y * p[1] + N.z * p[2] + N.w * p[3];
}

real3 bilinear3(real3 p[4], real xi, real eta) {
    real4 N = shape_functions(xi, eta);
    return N.x * p[0] + N.y * p[1] + N.z * p[2] + N.w * p[3];
}

bool inside(real xi, real eta, real tol) {
    return abs(xi) <= 1.0 + tol && abs(eta) <= 1.0 + tol;
}

// One Gauss-Newton update (paper eqs. 5-9); det = 0 means a singular Jacobian.
void newton_step(real2 p[4], real xi, real eta, real2 q, out real dxi, out real deta, out real det) {
    real2 f = bilinear2(p, xi, eta) - q;
    real2 a = 0.25 * ((p[1] - p[0]) * (1.0 - eta) + (p[2] - p[3]) * (1.0 + eta));
    real2 b = 0.25 * ((p[3] - p[0]) * (1.0 - xi) + (p[2] - p[1]) * (1.0 + xi));
    det = a.x * b.y - a.y * b.x;
    real inv = det == 0.0 ? 0.0 : 1.0 / det;
    dxi = -(b.y * f.x - b.x * f.y) * inv;
    deta = -(a.x * f.y - a.y * f.x) * inv;
}

// The paper's inverse mapping: Gauss-Newton from (0, 0) until |delta| <= NEWTON_TOL.
// Works relative to corner 0, which keeps float32 residuals at the element's scale.
bool invert_newton(real2 p[4], real2 q, out real xi, out real eta) {
    real2 o = p[0];
    for (int i = 0; i < 4; ++i) p[i] -= o;
    q -= o;
    xi = 0.0;
    eta = 0.0;
    for (int i = 0; i < NEWTON_MAX_ITER; ++i) {
        real dxi, deta, det;
        newton_step(p, xi, eta, q, dxi, deta, det);
        if (det == 0.0) return false;
        dxi = clamp(dxi, -4.0, 4.0);
        deta = clamp(deta, -4.0, 4.0);
        xi += dxi;
        eta += deta;
        if (max(abs(dxi), abs(deta)) <= NEWTON_TOL) return true;
    }
    return false;
}

// Both roots of the inverse map in closed form (A t^2 + B t + C = 0 with s = (xi+1)/2,
// t = (eta+1)/2), each polished by two Newton steps; ok[k] marks real roots.
void invert_closed(real2 p[4], real2 q, out real xi[2], out real eta[2], out bool ok[2]) {
    real2 e = p[1] - p[0], f = p[3] - p[0], g = p[0] - p[1] + p[2] - p[3], h = q - p[0];
    real A = cross2(f, g);
    real B = cross2(f, e) - cross2(h, g);
    real C = -cross2(h, e);
    real scale = abs(A) + abs(B) + abs(C);
    bool linear = abs(A) <= 1e-12 * (scale == 0.0 ? 1.0 : scale);
    real disc = B * B - 4.0 * A * C;
    real sq = sqrt(max(disc, 0.0));
    real Q = -0.5 * (B + (B >= 0.0 ? sq : -sq));
    real t[2];
    bool good[2];
    t[0] = linear ? -C / (B == 0.0 ? 1.0 : B) : Q / (A == 0.0 ? 1.0 : A);
    t[1] = Q == 0.0 ? t[0] : C / Q;
    good[0] = linear ? B != 0.0 : disc >= 0.0;
    good[1] = good[0] && !linear;
    for (int k = 0; k < 2; ++k) {
        real tk = good[k] ? t[k] : 0.5;
        real2 den = e + tk * g;
        real dd = dot(den, den);
        real s = dot(h - tk * f, den) / (dd == 0.0 ? 1.0 : dd);
        real x = 2.0 * s - 1.0, y = 2.0 * tk - 1.0;
        // roots far outside the element are rejected before polishing (saves half the work)
        bool near = abs(x) <= POLISH_RANGE && abs(y) <= POLISH_RANGE;
        for (int i = 0; i < 2 && near; ++i) {
            real dx, dy, det;
            newton_step(p, x, y, q, dx, dy, det);
            x += dx;
            y += dy;
        }
        ok[k] = good[k] && near && dd != 0.0 && !isnan(x) && !isnan(y) && !isinf(x) && !isinf(y);
        xi[k] = ok[k] ? x : 0.0;
        eta[k] = ok[k] ? y : 0.0;
    }
}

// Nearest intersection of the camera ray through normalized image point xn (the ray from the
// origin along (x, y, 1)) with the bilinear patch P (camera frame, mm): X - x Z = 0 and
// Y - y Z = 0 are two planes through the ray; at the corners they give a 2-D inverse bilinear
// problem with target (0, 0).
bool intersect_ray_patch(real3 P[4], real2 xn, out real xi, out real eta, out real Z) {
    real2 p[4];
    for (int i = 0; i < 4; ++i) p[i] = P[i].xy - xn * P[i].z;
    real xs[2], es[2];
    bool ok[2];
    invert_closed(p, real2(0.0), xs, es, ok);
    bool found = false;
    xi = 0.0;
    eta = 0.0;
    Z = 0.0;
    for (int k = 0; k < 2; ++k) {
        real z = dot(shape_functions(xs[k], es[k]), real4(P[0].z, P[1].z, P[2].z, P[3].z));
        if (ok[k] && inside(xs[k], es[k], INSIDE_TOL) && z > 0.0 && (!found || z < Z)) {
            found = true;
            xi = xs[k];
            eta = es[k];
            Z = z;
        }
    }
    return found;
}
