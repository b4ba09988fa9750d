// Mapping one sample of modes exact and q4 into an element (paper §2.1): where on the element
// the sample's ray or pixel point lands (xi, eta), its depth Z and the element's undeformed
// point in the reference image. The records it reads: records.glsl; the tie rule: bilinear.glsl.
#include "camera.glsl"
#include "bilinear.glsl"
#include "view.glsl"
#include "records.glsl"
#ifdef QUADRATIC
// quadratic elements: the records are their linear pieces; map on the curved patch
#if defined(MODE_Q4)
uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;
#endif
#include "quadratic.glsl"
#endif
#include "reference.glsl"
#if defined(MODE_EXACT)
#include "raymap.glsl"
layout(binding = SAMPLER_RAYS) uniform RAY_SAMPLER u_rays;   // rays.frag: per-sample undistorted normalized coordinates
uniform real u_ref_intr[5];
uniform real u_ref_dist[12];
uniform real u_ref_valid_r2;
#endif

real2 ref_lo = real2(0.0);   // REF_LOCAL: what float32 dropped from the last mapped ref (truth)

#if defined(MODE_EXACT) && !defined(QUADRATIC)
// Element e's corners in the camera frame (mm), from view.comp's records.
void element_camera(int e, out real3 P[4]) {
#ifdef CAMERA_LOCAL
    int l = 32 * e;
    #pragma unroll
    for (int i = 0; i < 4; ++i) P[i] = real3(elem_local[l + 3 * i], elem_local[l + 3 * i + 1], elem_local[l + 3 * i + 2]);
#else
    int b = e * 12;
    #pragma unroll
    for (int i = 0; i < 4; ++i) P[i] = real3(elem_data[b + 3 * i], elem_data[b + 3 * i + 1], elem_data[b + 3 * i + 2]);
#endif
}

// The 2-D problem of the ray (xn + lo, 1) at element e's corners: p = P.xy - xn P.z (mm). With
// CAMERA_LOCAL, (D.xy - xn D.z) - C.z (xn - C.xy / C.z) with D = P - C, so that float32 never
// subtracts the ~100 mm terms of nearly equal size that P.xy - xn P.z does.
void projected_corners(int e, real3 P[4], real2 xn, real2 lo, out real2 p[4]) {
#ifdef CAMERA_LOCAL
    int l = 32 * e;
    float cz = elem_local[l + 24];
    if (cz > 0.0) {
        // the high halves' difference is exact (they are close), the low ones' small; `precise`:
        // a hi/lo pair regrouped as (xn + lo) - (C_hi + C_lo) would lose the low halves
        precise vec2 d = (xn - vec2(elem_local[l + 26], elem_local[l + 27])) + (lo - vec2(elem_local[l + 28], elem_local[l + 29]));
        #pragma unroll
        for (int i = 0; i < 4; ++i) {
            vec3 D = vec3(elem_local[l + 12 + 3 * i], elem_local[l + 13 + 3 * i], elem_local[l + 14 + 3 * i]);
            p[i] = (D.xy - xn * D.z) - cz * d;
        }
        return;
    }
#endif
    #pragma unroll
    for (int i = 0; i < 4; ++i) p[i] = P[i].xy - xn * P[i].z;
}

// The reference-image point of (xi, eta) on element e (the undeformed point seen by the
// reference camera); false where that camera cannot project it.
bool exact_reference(int e, real xi, real eta, out real2 ref) {
    bool ref_ok;
#ifdef REF_LOCAL
    // X = C + D(xi, eta): xn(X) - xn(C) = (D.xy C.z - C.xy D.z) / (C.z (C.z + D.z)), small and
    // exact to float32's relative precision, added to C's pixel kept as hi + lo
    int r = e * 20;
    real3 D[4];
    #pragma unroll
    for (int i = 0; i < 4; ++i) D[i] = real3(ref_local[r + 3 * i], ref_local[r + 3 * i + 1], ref_local[r + 3 * i + 2]);
    real3 d = bilinear3(D, xi, eta);
    real3 C = real3(ref_local[r + 12], ref_local[r + 13], ref_local[r + 14]);
    real zd = C.z + d.z;
    real2 dxn = (d.xy * C.z - C.xy * d.z) / (C.z * zd);
    real2 duv = real2(u_ref_intr[0] * dxn.x + u_ref_intr[2] * dxn.y, u_ref_intr[1] * dxn.y);
    real2 hi = real2(ref_local[r + 16], ref_local[r + 17]);
    // Fast2Sum (|hi| >= |lo| here): ref and what the float32 sum dropped, `precise` so that no
    // compiler folds (lo - ((hi + lo) - hi)) to 0
    precise real2 lo = real2(ref_local[r + 18], ref_local[r + 19]) + duv;
    precise real2 sum = hi + lo;
    precise real2 back = sum - hi;
    precise real2 dropped = lo - back;
    ref = sum;
    ref_lo = dropped;
    real2 xn_ref = C.xy / C.z + dxn;
    ref_ok = zd > 0.0 && dot(xn_ref, xn_ref) < u_ref_valid_r2;
#elif defined(REF_PINHOLE)
    // the pinhole projection of the blended corners: (fx X + skew Y + cx Z, fy Y + cy Z) / Z
    int r = e * 12;
    real3 R[4];
    #pragma unroll
    for (int i = 0; i < 4; ++i) R[i] = real3(ref_pinhole[r + 3 * i], ref_pinhole[r + 3 * i + 1], ref_pinhole[r + 3 * i + 2]);
    real3 w = bilinear3(R, xi, eta);
    ref_ok = w.z > 0.0;
    ref = ref_ok ? w.xy / w.z : real2(0.0);
#else
    ivec4 q = quads[e];
    real3 R[4];  // undeformed corners in the reference camera's frame (mm)
    #pragma unroll
    for (int i = 0; i < 4; ++i) R[i] = real3(ref_xr[3 * q[i]], ref_xr[3 * q[i] + 1], ref_xr[3 * q[i] + 2]);
    ref_ok = project_camera_frame(bilinear3(R, xi, eta), u_ref_intr, u_ref_dist, u_ref_valid_r2, ref);
#endif
    return ref_ok;
}
#endif

// Map this sample (pixel point px; ray xn in mode exact) into element e: false where e does
// not own it (the tie rule); ref_ok false where it does but its reference point lies outside
// the reference image (or the reference camera cannot project it).
bool map_sample(int e, real2 px, real2 xn, out real xi, out real eta, out real2 ref, out real Z, out bool ref_ok) {
    int b = e * 12;
    ref = real2(0.0);
    ref_ok = false;
#if defined(QUADRATIC)
    // the patch of piece e: Newton on its 9 nodes (quadratic.glsl)
    int pid, ci, cj;
    piece_cell(e, pid, ci, cj);
    real z[9];
    real2 pp[9];
    real3 Q[9];
    #pragma unroll
    for (int i = 0; i < 9; ++i) { Q[i] = patch_camera(pid, i); z[i] = Q[i].z; }
    real N[9];
#if defined(MODE_Q4)
    #pragma unroll
    for (int i = 0; i < 9; ++i) {
        if (!project_camera_frame(Q[i], u_intr, u_dist, u_valid_r2, pp[i])) return false;
    }
    if (!q9_invert_piece(e, pp, z, px, xi, eta, Z)) return false;
    q9_shape(xi, eta, N);
    #pragma unroll
    for (int i = 0; i < 9; ++i) ref += N[i] * real2(patch_ref[18 * pid + 2 * i], patch_ref[18 * pid + 2 * i + 1]);
    ref_ok = true;
#else
    #pragma unroll
    for (int i = 0; i < 9; ++i) pp[i] = Q[i].xy - xn * Q[i].z;
    if (!q9_invert_piece(e, pp, z, real2(0.0), xi, eta, Z)) return false;
    q9_shape(xi, eta, N);
    real3 X = real3(0.0);
    #pragma unroll
    for (int i = 0; i < 9; ++i) {
        int r = 27 * pid + 3 * i;
        X += N[i] * real3(patch_ref[r], patch_ref[r + 1], patch_ref[r + 2]);
    }
    ref_ok = project_camera_frame(X, u_ref_intr, u_ref_dist, u_ref_valid_r2, ref);
#endif
#elif defined(MODE_Q4)
    real2 p[4];
    #pragma unroll
    for (int i = 0; i < 4; ++i) p[i] = real2(elem_data[b + 2 * i], elem_data[b + 2 * i + 1]);
    Z = 0.0;
    if (!invert_newton(p, px, xi, eta) || !in_range(xi, eta)) return false;
    if (near_edge(xi, eta)) {
        real E[4];
        real2 m[4];
        edge_functions_2d(p, px, E, m);
        if (!owned(xi, eta, E, m, orientation_2d(p, xi, eta))) return false;
    }
    ivec4 q = quads[e];
    real2 r[4];
    #pragma unroll
    for (int i = 0; i < 4; ++i) r[i] = real2(ref_uv[2 * q[i]], ref_uv[2 * q[i] + 1]);
    ref = bilinear2(r, xi, eta);
    Z = dot(shape_functions(xi, eta), real4(elem_data[b + 8], elem_data[b + 9], elem_data[b + 10], elem_data[b + 11]));
    ref_ok = true;
#else
    real3 P[4];
    element_camera(e, P);
    real2 p[4];
    projected_corners(e, P, xn, ray_lo, p);
    if (!intersect_ray_patch_p(P, p, quads[e], xn, px, xi, eta, Z)) return false;
    ref_ok = exact_reference(e, xi, eta, ref);
#endif
    ref_ok = ref_ok && inside_reference(ref);
    return true;
}
