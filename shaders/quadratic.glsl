// Quadratic elements as 9-node biquadratic patches: the GLSL twin of glsim/scene/quadratic.py
// (node order: corners, mid-sides of edges 0-1, 1-2, 2-3, 3-0, centre; N_i = L_a(xi) L_b(eta)).
// Compile-time: QUADRATIC, PIECES (the linear pieces per element side that the element
// records, covers and candidate lists are made of: piece e belongs to patch e / PIECES^2 and
// spans the patch's cell (e % PIECES, (e / PIECES) % PIECES) of its PIECES x PIECES grid).
// Uses view.glsl (u_rot, u_trans), camera.glsl and bilinear.glsl (invert_closed).
#include "camera.glsl"
#include "bilinear.glsl"
#include "view.glsl"
#ifdef FP64
#define Q_TOL 1e-13lf          // stop once max(|dxi|, |deta|) <= Q_TOL ...
#define Q_RESIDUAL 1e-9lf      // ... or after Q_MAX_ITER accept a residual <= this x the patch size
#else
#define Q_TOL 1e-6
#define Q_RESIDUAL 1e-5
#endif
#define Q_MAX_ITER 30
#define Q_INSIDE real(1e-9lf)       // |xi|, |eta| <= 1 + Q_INSIDE (and a piece's share likewise)
#define Q_START_RANGE 1.25   // a piece root farther out than this (piece coordinates) is no start

// per patch: its 9 control points in the mesh's local frame at this load step (binding PATCH_NODES) and,
// uploaded once, in the reference camera's frame (exact, 27) or as reference-image px (q4, 18)
layout(std430, binding = BINDING_PATCH_NODES) readonly buffer PatchNodes { real patch_nodes[]; };
layout(std430, binding = BINDING_PATCH_REF) readonly buffer PatchRef { real patch_ref[]; };

const int Q_IA[9] = int[9](0, 2, 2, 0, 1, 2, 1, 0, 1);
const int Q_IB[9] = int[9](0, 0, 2, 2, 0, 1, 2, 1, 1);

real3 lagrange3(real t) { return real3(0.5 * t * (t - 1.0), 1.0 - t * t, 0.5 * t * (t + 1.0)); }
real3 dlagrange3(real t) { return real3(t - 0.5, -2.0 * t, t + 0.5); }

void q9_shape(real xi, real eta, out real N[9]) {
    real3 a = lagrange3(xi), b = lagrange3(eta);
    #pragma unroll
    for (int i = 0; i < 9; ++i) N[i] = a[Q_IA[i]] * b[Q_IB[i]];
}

real3 patch_camera(int p, int k) {
    int b = 27 * p + 3 * k;
    real3 x = real3(patch_nodes[b], patch_nodes[b + 1], patch_nodes[b + 2]);
    return real3(u_rot[0] * x.x + u_rot[1] * x.y + u_rot[2] * x.z + u_trans[0],
                 u_rot[3] * x.x + u_rot[4] * x.y + u_rot[5] * x.z + u_trans[1],
                 u_rot[6] * x.x + u_rot[7] * x.y + u_rot[8] * x.z + u_trans[2]);
}

// Newton on sum N_i(xi, eta) p_i = q from (xi, eta); the stopping rule of
// glsim.scene.quadratic.newton (relative to the centre node; steps clipped to +-1).
bool q9_newton(real2 p[9], real2 q, real scale, inout real xi, inout real eta) {
    real2 o = p[8];
    #pragma unroll
    for (int i = 0; i < 9; ++i) p[i] -= o;
    q -= o;
    for (int it = 0; it < Q_MAX_ITER; ++it) {
        real3 a = lagrange3(xi), b = lagrange3(eta), da = dlagrange3(xi), db = dlagrange3(eta);
        real2 f = -q, ja = real2(0.0), jb = real2(0.0);
        #pragma unroll
        for (int i = 0; i < 9; ++i) {
            f += a[Q_IA[i]] * b[Q_IB[i]] * p[i];
            ja += da[Q_IA[i]] * b[Q_IB[i]] * p[i];
            jb += a[Q_IA[i]] * db[Q_IB[i]] * p[i];
        }
        real det = ja.x * jb.y - ja.y * jb.x;
        if (det == 0.0 || isnan(det) || isinf(det)) return false;
        real dx = clamp(-(jb.y * f.x - jb.x * f.y) / det, -1.0, 1.0);
        real dy = clamp(-(ja.x * f.y - ja.y * f.x) / det, -1.0, 1.0);
        xi += dx;
        eta += dy;
        if (max(abs(dx), abs(dy)) <= Q_TOL) return !(isnan(xi) || isnan(eta));
    }
    real N[9];
    q9_shape(xi, eta, N);
    real2 f = -q;
    #pragma unroll
    for (int i = 0; i < 9; ++i) f += N[i] * p[i];
    return length(f) <= Q_RESIDUAL * scale && !(isnan(xi) || isnan(eta));
}

// Patch e / PIECES^2's coordinates of piece e's local (xs, ys), and back.
void piece_cell(int e, out int pid, out int ci, out int cj) {
    pid = e / (PIECES * PIECES);
    int k = e - pid * PIECES * PIECES;
    ci = k % PIECES;
    cj = k / PIECES;
}

bool in_piece(int ci, int cj, real xi, real eta) {
    real h = 2.0 / real(PIECES);
    real lo_x = -1.0 + h * real(ci), lo_y = -1.0 + h * real(cj);
    return abs(xi) <= 1.0 + Q_INSIDE && abs(eta) <= 1.0 + Q_INSIDE &&
           xi >= lo_x - Q_INSIDE && xi <= lo_x + h + Q_INSIDE && eta >= lo_y - Q_INSIDE && eta <= lo_y + h + Q_INSIDE;
}

// The 2x2 bilinear sub-quads through the 9 nodes (glsim.scene.quadratic.sub_quads(P, 2)):
// sub-quad s = 2 j + i spans xi in [-1 + i, i], eta in [-1 + j, j].
const int Q_SUB[16] = int[16](0, 4, 8, 7,  4, 1, 5, 8,  7, 8, 6, 3,  8, 5, 2, 6);

// Sub-quad s's corners: the points indexed by constants only (s selects one written-out copy).
void piece_corners(real2 pp[9], int s, out real2 sub[4]) {
    #pragma unroll
    for (int t = 0; t < 4; ++t) {
        if (s == t) {
            #pragma unroll
            for (int i = 0; i < 4; ++i) sub[i] = pp[Q_SUB[4 * t + i]];
        }
    }
}

// The patch point of piece e's share that maps to q under the patch's 2-D map (points pp) and
// is nearest (patch depths z): Newton from the starts of glsim.scene.quadratic.starts — both
// closed-form roots of each 2x2 sub-quad within Q_START_RANGE of it, and always its centre (beside
// a silhouette the chords can be crossed near the farther root only) — so GL and the oracle
// search the same roots; a root counts for the piece whose share
// (within Q_INSIDE) holds it. false where none.
bool q9_invert_piece(int e, real2 pp[9], real z[9], real2 q, out real xi, out real eta, out real Z) {
    int pid, ci, cj;
    piece_cell(e, pid, ci, cj);
    real2 lo = pp[0], hi = pp[0];
    #pragma unroll
    for (int i = 1; i < 9; ++i) { lo = min(lo, pp[i]); hi = max(hi, pp[i]); }
    real scale = max(hi.x - lo.x, hi.y - lo.y);
    bool found = false;
    xi = 0.0; eta = 0.0; Z = 0.0;
    for (int s = 0; s < 4; ++s) {
        real2 sub[4];
        piece_corners(pp, s, sub);
        real xs[2], ys[2];
        bool ok[2], usable[3];
        invert_closed(sub, q, xs, ys, ok);
        #pragma unroll
        for (int k = 0; k < 2; ++k) usable[k] = ok[k] && abs(xs[k]) <= Q_START_RANGE && abs(ys[k]) <= Q_START_RANGE;
        usable[2] = true;
        for (int k = 0; k < 3; ++k) {
            if (!usable[k]) continue;
            // (a variable index into xs would put them in NVIDIA's float32 memory: README, glsim check)
            real sx = k == 0 ? xs[0] : k == 1 ? xs[1] : 0.0, sy = k == 0 ? ys[0] : k == 1 ? ys[1] : 0.0;
            real x = -1.0 + (2.0 * real(s % 2) + 1.0 + sx) * 0.5;
            real y = -1.0 + (2.0 * real(s / 2) + 1.0 + sy) * 0.5;
            if (!q9_newton(pp, q, scale, x, y) || !in_piece(ci, cj, x, y)) continue;
            real N[9];
            q9_shape(x, y, N);
            real zz = 0.0;
            #pragma unroll
            for (int i = 0; i < 9; ++i) zz += N[i] * z[i];
            if (!(zz > 0.0) || (found && zz >= Z)) continue;
            found = true;
            xi = x; eta = y; Z = zz;
        }
    }
    return found;
}
