// Inverse bilinear (Q4) mapping and ray / bilinear-patch intersection: the GLSL twin of
// glsim/scene/bilinear.py (same names and steps). Corners in FE order 0:(-1,-1) 1:(1,-1) 2:(1,1) 3:(-1,1).
// Coverage follows the tie rule of glsim/scene/bilinear.py (owned): near an edge the edge
// function decides, computed `precise` (no fused multiply-add) so that two elements sharing
// an edge get exactly opposite values; exact ties go to the element on the +x (then +y) side.
#ifdef FP64
#define NEWTON_TOL 1e-12lf
#define NEAR_TOL 1e-6lf
#else
#define NEWTON_TOL 1e-6
#define NEAR_TOL 1e-3
#endif
#define NEWTON_MAX_ITER 20
#define POLISH_RANGE 1.5  // closed-form roots beyond |xi|, |eta| > 1.5 are not polished
#ifdef PIXEL_TIES
uniform real u_intr[5];   // the view camera (pinhole): the tie rule in pixel space (intersect_ray_patch_p)
#endif

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

#include "ties.glsl"

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
    #pragma unroll
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
    bool linear = abs(A) <= real(1e-12lf) * (scale == 0.0 ? 1.0 : scale);
    real disc = B * B - 4.0 * A * C;
    real sq = sqrt(max(disc, 0.0));
    real Q = -0.5 * (B + (B >= 0.0 ? sq : -sq));
    real t[2];
    bool good[2];
    t[0] = linear ? -C / (B == 0.0 ? 1.0 : B) : Q / (A == 0.0 ? 1.0 : A);
    t[1] = Q == 0.0 ? t[0] : C / Q;
    good[0] = linear ? B != 0.0 : disc >= 0.0;
    good[1] = good[0] && !linear;
    #pragma unroll
    for (int k = 0; k < 2; ++k) {
        ok[k] = false;
        xi[k] = 0.0;
        eta[k] = 0.0;
        // a root with |eta| > POLISH_RANGE is rejected below; t[0] = Q / A is such a root
        // wherever |Q| > (1 + POLISH_RANGE) / 2 |A| (as for near-parallelogram patches): the
        // loop form lets llvmpipe skip the block when every lane of a vector can (same results)
        bool may = good[k] && (k == 1 || linear || abs(Q) <= 0.5 * (1.0 + POLISH_RANGE) * abs(A));
        for (bool once = may; once; once = false) {
            real tk = t[k];
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
            ok[k] = near && dd != 0.0 && !isnan(x) && !isnan(y) && !isinf(x) && !isinf(y);
            xi[k] = ok[k] ? x : 0.0;
            eta[k] = ok[k] ? y : 0.0;
        }
    }
}

// Nearest intersection of the camera ray through normalized image point xn (the ray from the
// origin along (x, y, 1)) with the bilinear patch P (camera frame, mm): X - x Z = 0 and
// Y - y Z = 0 are two planes through the ray; at the corners they give a 2-D inverse bilinear
// problem with target (0, 0), p = P.xy - xn P.z, given here (sample_map.glsl's CAMERA_LOCAL makes
// it relative to the element's centre in float32). A root counts where the tie rule (owned)
// gives it to this element; PIXEL_TIES (a pinhole camera, u_intr above) decides it in pixel
// space at the sample's pixel point px. q: the element's node indices (float32 builds' edge
// function order).
bool intersect_ray_patch_p(real3 P[4], real2 p[4], ivec4 q, real2 xn, real2 px, out real xi, out real eta, out real Z) {
    real xs[2], es[2];
    bool ok[2];
    invert_closed(p, real2(0.0), xs, es, ok);
    bool found = false;
    xi = 0.0;
    eta = 0.0;
    Z = 0.0;
    #pragma unroll
    for (int k = 0; k < 2; ++k) {
        real z = dot(shape_functions(xs[k], es[k]), real4(P[0].z, P[1].z, P[2].z, P[3].z));
        if (!(ok[k] && z > 0.0 && (!found || z < Z) && in_range(xs[k], es[k]))) continue;
        for (bool once = near_edge(xs[k], es[k]); once; once = false) {  // the tie rule
            real E[4];
            real2 m[4];
            real3 A[4];   // the corners and point the edge functions take
            real2 at;
#ifdef PIXEL_TIES
            pinhole_corners(P, u_intr, A);
            at = px;
#else
            A = P;
            at = xn;
#endif
#ifdef FP64
            edge_functions_ray(A, at, E, m);
#else
            edge_functions_ray_ordered(A, q, at, E, m);
#endif
            if (!owned(xs[k], es[k], E, m, orientation_ray(P, xs[k], es[k]))) ok[k] = false;
        }
        if (!ok[k]) continue;
        found = true;
        xi = xs[k];
        eta = es[k];
        Z = z;
    }
    return found;
}

