// The tie rule of glsim/scene/bilinear.py (owned), the GLSL twin of its functions: edge
// functions, computed `precise` (no fused multiply-add) so that two elements sharing an edge get
// exactly opposite values, and the local orientation; exact ties go to the element on the +x
// (then +y) side. Part of bilinear.glsl, which includes it (cross2, shape_functions, NEAR_TOL).

// Edge functions of the 2-D quad p at q (edge k from corner k to k+1): E = cross(p_i - q, p_j - q),
// positive left of i -> j, and its gradient m in q.
void edge_functions_2d(real2 p[4], real2 q, out real E[4], out real2 m[4]) {
    #pragma unroll
    for (int k = 0; k < 4; ++k) {
        const int j = (k + 1) & 3;
        precise real2 a = p[k] - q;
        precise real2 b = p[j] - q;
        precise real e = a.x * b.y - a.y * b.x;
        E[k] = e;
        m[k] = real2(p[k].y - p[j].y, p[j].x - p[k].x);
    }
}

// The edge function of the plane through the origin, a and b at the ray (xn, 1): E = (xn, 1) .
// (a x b), and its gradient m in xn; `precise` (no fused multiply-add), so that E(a, b) and
// E(b, a) are exactly opposite.
void edge_function(real3 a, real3 b, real2 xn, out real E, out real2 m) {
    precise real mx = a.y * b.z - a.z * b.y;
    precise real my = a.z * b.x - a.x * b.z;
    precise real mz = a.x * b.y - a.y * b.x;
    precise real e = (xn.x * mx + xn.y * my) + mz;
    E = e;
    m = real2(mx, my);
}

// Edge functions of patch P for the ray (xn, 1): E = (xn, 1) . (P_i x P_j), and the gradient in xn.
// With pinhole_corners(P) and the sample's pixel point for xn, the same in pixel space.
void edge_functions_ray(real3 P[4], real2 xn, out real E[4], out real2 m[4]) {
    #pragma unroll
    for (int k = 0; k < 4; ++k) edge_function(P[k], P[(k + 1) & 3], xn, E[k], m[k]);
}

#ifndef FP64
// Float32 builds: the same edge functions, each edge's from its first corner in the mesh's node
// order q as a x (b - a) (= a x b): float32 then rounds products of ~|P| coordinates with the
// edge's length, not with another ~|P| (so a sample is decided to within about 2^-24 |P| of the
// edge, not |P|/length times that: glsim.evaluation.exact32.edge_px); one order for both
// elements of an edge, negated for the one that runs it backwards, keeps them exactly opposite.
// (Float64 builds keep P_i x P_j, the oracle's to the bit.)
void edge_functions_ray_ordered(real3 P[4], ivec4 q, real2 xn, out real E[4], out real2 m[4]) {
    #pragma unroll
    for (int k = 0; k < 4; ++k) {
        const int j = (k + 1) & 3;
        bool back = q[k] > q[j];
        real3 a = back ? P[j] : P[k];
        precise real3 d = (back ? P[k] : P[j]) - a;
        real e;
        real2 g;
        edge_function(a, d, xn, e, g);
        real s = back ? -1.0 : 1.0;
        E[k] = s * e;
        m[k] = s * g;
    }
}
#endif

// K P of camera-frame corners for pinhole intrinsics intr (fx, fy, skew, cx, cy): (u, v, 1) .
// (A_i x A_j) is fx fy times the ray's edge function, measured from the sample's pixel point,
// which is exact, instead of its rounded ray (glsim.scene.bilinear.pinhole_corners).
void pinhole_corners(real3 P[4], real intr[5], out real3 A[4]) {
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        precise real a = (intr[0] * P[i].x + intr[2] * P[i].y) + intr[3] * P[i].z;
        precise real b = intr[1] * P[i].y + intr[4] * P[i].z;
        A[i] = real3(a, b, P[i].z);
    }
}

// The tie rule for one edge (orientation s = +-1): s E > 0, or s E == 0 and the inward normal
// s m points to +x, or with zero x to +y. A collapsed edge (m = 0) decides nothing.
bool edge_owns(real E, real2 m, real s) {
    if (m.x == 0.0 && m.y == 0.0) return true;
    precise real sE = s * E;
    precise real2 sm = s * m;
    return sE > 0.0 || (sE == 0.0 && (sm.x > 0.0 || (sm.x == 0.0 && sm.y > 0.0)));
}

bool in_range(real xi, real eta) { return abs(xi) <= 1.0 + NEAR_TOL && abs(eta) <= 1.0 + NEAR_TOL; }

// Within NEAR_TOL of an edge: only there the edge functions are needed (callers skip them elsewhere).
bool near_edge(real xi, real eta) { return max(abs(xi), abs(eta)) >= 1.0 - NEAR_TOL; }

// Coverage under the tie rule: (xi, eta) within NEAR_TOL of the element, and every edge the
// sample is within NEAR_TOL of owns it.
bool owned(real xi, real eta, real E[4], real2 m[4], real s) {
    if (!in_range(xi, eta)) return false;
    bool near[4] = bool[4](eta <= -1.0 + NEAR_TOL, xi >= 1.0 - NEAR_TOL, eta >= 1.0 - NEAR_TOL,
                           xi <= -1.0 + NEAR_TOL);
    #pragma unroll
    for (int k = 0; k < 4; ++k)
        if (near[k] && !edge_owns(E[k], m[k], s)) return false;
    return true;
}

real sign_or(real a, real b) { return a != 0.0 ? sign(a) : sign(b); }

// Local orientation of the 2-D map at (xi, eta): sign(det J), else the sign of the signed area.
real orientation_2d(real2 p[4], real xi, real eta) {
    real2 a = 0.25 * ((p[1] - p[0]) * (1.0 - eta) + (p[2] - p[3]) * (1.0 + eta));
    real2 b = 0.25 * ((p[3] - p[0]) * (1.0 - xi) + (p[2] - p[1]) * (1.0 + xi));
    real area = cross2(p[1] - p[0], p[2] - p[0]) + cross2(p[2] - p[0], p[3] - p[0]);
    return sign_or(a.x * b.y - a.y * b.x, area);
}

// Local orientation of patch P seen from the camera centre: sign(X . (X_xi x X_eta)), else the
// sign of the volume of the pyramid camera-quad.
real orientation_ray(real3 P[4], real xi, real eta) {
    real3 a = 0.25 * ((P[1] - P[0]) * (1.0 - eta) + (P[2] - P[3]) * (1.0 + eta));
    real3 b = 0.25 * ((P[3] - P[0]) * (1.0 - xi) + (P[2] - P[1]) * (1.0 + xi));
    real vol = dot(P[0], cross(P[1], P[2]) + cross(P[2], P[3]));
    return sign_or(dot(bilinear3(P, xi, eta), cross(a, b)), vol);
}
