// Grey value of each sample: map it to the reference image and interpolate (paper §2.1).
// Compile-time choices: MODE_FAST | MODE_Q4 | MODE_EXACT, INTERP_*, SS (samples per pixel
// per axis), FP64 (double arithmetic), TRUTH (also write the truth maps; TRUTH_LO with FP64:
// the low halves of (xi, eta) too), LIGHTING (Phong,
// shade.glsl), DEPTH_OUT (write camera-frame depth Z at DEPTH_LOCATION, for depth of field).
//
// Modes exact and q4 read candidate lists: pass 1 (candidates.comp) listed, per pixel, the
// elements whose cover may hold one of its samples. Then, each over its own pixels:
// - this file as a full-screen pass (lists.vert): pixels with one candidate, straight-line;
// - RESOLVE (resolve.frag, full screen): pixels with 2..CANDIDATES candidates; each sample
//   tests every candidate and keeps the nearest owner (ties: the lower element index, as the
//   oracle), an owner mapping outside the reference giving way to one behind it;
// - FALLBACK (exact.vert over the cover rectangles, depth test): pixels whose list overflowed,
//   one element per fragment, as every pixel was drawn before the lists.
// classify.frag sorted the samples into depth layers by their pixel's count, and the two
// full-screen passes run with EARLY_TESTS on their own layer only. The exact test and the
// shared tie rule decide coverage in all three. With PIXEL_LOOP (subsamples.frag) this file
// supplies the functions and that file the main.
// COMPUTE_PIXELS (deform.comp, resolve.comp; glsim.backends.gl.plan's pixel stage "compute"):
// the first two as compute passes, one invocation per sample of the pixels in classify.comp's
// list of their layer (pixellists.glsl), writing the targets as images; a sample the fragment
// passes discard is left as cleared alike. Mode fast in that stage: FAST_VISIBILITY draws the
// triangles as before but writes only each sample's triangle (fast.geom keeps their records),
// then deform.comp shades every sample of the target from its triangle's record.
#if defined(COMPUTE_PIXELS)
#if defined(FALLBACK) || defined(PIXEL_LOOP)
#error "COMPUTE_PIXELS: the exact and q4 full-screen passes and mode fast only"
#endif
#ifdef MODE_FAST
layout(local_size_x = 16, local_size_y = 8) in;
#else
#include "pixellists.glsl"
layout(local_size_x = LIST_LOCAL) in;
#endif
#define FRAG_COORD (vec2(at) + 0.5)   // the sample shade_sample is given
#define DROP return
#else
#define FRAG_COORD gl_FragCoord.xy
#define DROP discard
#endif
#ifdef EARLY_TESTS
// the full-screen passes: the depth test (classify.frag's layers) runs before the shader
layout(early_fragment_tests) in;
#endif
#include "camera.glsl"
#include "interp.glsl"
#if defined(PIXEL_TIES)
uniform real u_intr[5];   // the view camera (pinhole): bilinear.glsl's tie rule in pixel space
#endif
#include "bilinear.glsl"
#include "hilo.glsl"
#if !defined(MODE_FAST) || defined(LIGHTING)
// the mesh (connectivity, the step's nodes) and the camera transform
#include "view.glsl"
#endif
#ifdef LIGHTING
#include "shade.glsl"
// per element: the step's unit corner normals in the world frame (12), float32, uploaded once
// per step (glsim.backends.gl.geometry.GeometryBuffers.normals); rotated here by u_rot
layout(std430, binding = BINDING_NORMALS) readonly buffer Normals { float corner_normals[]; };
#endif

uniform vec2 u_ref_size;  // reference image W, H (px)
uniform float u_far;      // depth range (mm): gl_FragDepth = Z / u_far

#if defined(MODE_FAST)
#include "fasttriangles.glsl"
#ifdef COMPUTE_PIXELS
// the triangle of each sample (FAST_VISIBILITY's target; 0: none) and, from its record, the
// values the fragment stage gets from fast.geom
layout(binding = SAMPLER_VISIBILITY) uniform usampler2D u_visibility;
vec2 g_uv[3], g_ref[3], g_xe[3];
float g_z[3];
int g_elem;
#else
// fast.geom: the triangle's projected vertices (px), reference points, (xi, eta) and depths
flat in vec2 g_uv[3];
flat in vec2 g_ref[3];
flat in vec2 g_xe[3];
flat in float g_z[3];
flat in int g_elem;
flat in int g_tri;
#endif
#else
// Per-view element records written by view.comp, float64 or float32 as `real`: exact: corners
// in the camera frame (12); q4: distorted pixel corners (8) and depths Z (4).
layout(std430, binding = BINDING_ELEMENTS) readonly buffer Elements { real elem_data[]; };
// the mesh, uploaded once per renderer (glsim.backends.gl.geometry): per node, reference-image
// coordinates (q4) or the undeformed position in the reference camera's frame (exact)
#if defined(MODE_Q4)
layout(std430, binding = BINDING_REF_UV) readonly buffer RefUV { real ref_uv[]; };
#else
layout(std430, binding = BINDING_REF_XR) readonly buffer RefXr { real ref_xr[]; };
#endif
#ifdef CAMERA_LOCAL
// float32 exact on a driver with float64: view.comp's RECORD_LOCAL records (32 per element)
layout(std430, binding = BINDING_LOCAL) readonly buffer Local { float elem_local[]; };
#endif
#ifdef REF_LOCAL
// float32 exact with a pinhole reference camera (glsim.backends.gl.geometry.ref_local_buffer):
// per element its reference-frame corners relative to their centre C (12), C (3), 0, and the
// reference pixel of C as hi (2) + lo (2), made in float64
layout(std430, binding = BINDING_REF_LOCAL) readonly buffer RefLocal { float ref_local[]; };
#endif
#ifdef REF_PINHOLE
// float64 exact with a pinhole reference camera (glsim.backends.gl.geometry.ref_pinhole_buffer):
// per element its reference-frame corners as (fx X + skew Y + cx Z, fy Y + cy Z, Z) (12)
layout(std430, binding = BINDING_REF_PINHOLE) readonly buffer RefPinhole { real ref_pinhole[]; };
#endif
#define CANDIDATE_TEXTURES
#include "candidates.glsl"
#ifdef QUADRATIC
// quadratic elements: the records above are their linear pieces; map on the curved patch
#if defined(MODE_Q4)
uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;
#endif
#include "quadratic.glsl"
#endif
#ifndef COMPUTE_PIXELS
flat in int v_elem;
#endif
#endif
// samples that hit the specimen but map outside the reference image (reset before each pass)
layout(std430, binding = BINDING_DROPPED) buffer Dropped { uint dropped_samples; };

#if defined(MODE_EXACT)
#include "raymap.glsl"
layout(binding = SAMPLER_RAYS) uniform RAY_SAMPLER u_rays;   // rays.frag: per-sample undistorted normalized coordinates
uniform real u_ref_intr[5];
uniform real u_ref_dist[12];
uniform real u_ref_valid_r2;
#endif

#ifdef COMPUTE_PIXELS
// the targets as images (their units: glsim.backends.gl.bindings.IMAGES); main stores the values
layout(r32f, binding = IMAGE_GREY) uniform writeonly image2D u_out_grey;
float out_grey;
#ifdef TRUTH
layout(rgba32f, binding = IMAGE_MAP) uniform writeonly image2D u_out_map;
layout(rgba32f, binding = IMAGE_EXTRA) uniform writeonly image2D u_out_extra;
vec4 out_map, out_extra;
#ifdef TRUTH_LO
layout(rg32f, binding = IMAGE_LO) uniform writeonly image2D u_out_lo;
vec2 out_lo;
#endif
#endif
#ifdef DEPTH_OUT
layout(r32f, binding = IMAGE_DEPTH) uniform writeonly image2D u_out_depth;
float out_depth;
#endif
#elif defined(FAST_VISIBILITY)
layout(location = 0) out uint out_triangle;   // the sample's triangle + 1 (fast.geom's records)
#else
layout(location = 0) out float out_grey;
#ifdef TRUTH
layout(location = 1) out vec4 out_map;     // ref u, ref v, xi, eta (float32)
layout(location = 2) out vec4 out_extra;   // element + 1, ref u and v rounding residuals
#ifdef TRUTH_LO
layout(location = 3) out vec2 out_lo;      // xi, eta rounding residuals (FP64: float64 truth as hi + lo)
#endif
#endif
#ifdef DEPTH_OUT
layout(location = DEPTH_LOCATION) out float out_depth;  // camera-frame Z (mm)
#endif
#endif

#ifdef LIGHTING
// Phong intensity at (xi, eta) of element e: surface point and interpolated unit normal, in
// the camera frame.
float light_at(int e, real xi, real eta) {
    vec3 X = vec3(0.0), N = vec3(0.0);
#ifdef QUADRATIC
    // e is a piece of a curved patch and (xi, eta) the patch's: the point on the patch, the
    // normal interpolated over the piece holding it (glsim.backends.cpu._shade)
    int pid, ci, cj;
    piece_cell(e, pid, ci, cj);
    real Nq[9];
    q9_shape(xi, eta, Nq);
    #pragma unroll
    for (int i = 0; i < 9; ++i) X += float(Nq[i]) * vec3(patch_camera(pid, i));
    real n2 = real(PIECES);
    real cx = clamp(floor((xi + 1.0) * n2 / 2.0), 0.0, n2 - 1.0), cy = clamp(floor((eta + 1.0) * n2 / 2.0), 0.0, n2 - 1.0);
    e = pid * PIECES * PIECES + int(cy) * PIECES + int(cx);
    vec4 w = vec4(shape_functions((xi + 1.0) * n2 - 2.0 * cx - 1.0, (eta + 1.0) * n2 - 2.0 * cy - 1.0));
    for (int i = 0; i < 4; ++i) {
        int b = e * 12 + 3 * i;
        N += w[i] * vec3(corner_normals[b], corner_normals[b + 1], corner_normals[b + 2]);
    }
#else
    vec4 w = vec4(shape_functions(xi, eta));
    ivec4 q = quads[e];
    for (int i = 0; i < 4; ++i) {
        int b = e * 12 + 3 * i;
        X += w[i] * vec3(node_camera(q[i]));
        N += w[i] * vec3(corner_normals[b], corner_normals[b + 1], corner_normals[b + 2]);
    }
#endif
    // u_rot is row-major; mat3() fills columns, so this is R
    N = transpose(mat3(float(u_rot[0]), float(u_rot[1]), float(u_rot[2]), float(u_rot[3]), float(u_rot[4]),
                       float(u_rot[5]), float(u_rot[6]), float(u_rot[7]), float(u_rot[8]))) * N;
    float n = length(N);
    return phong(X, n > 0.0 ? N / n : vec3(0.0));
}
#endif

#if !defined(MODE_FAST)
real2 ref_lo = real2(0.0);   // REF_LOCAL: what float32 dropped from the last mapped ref (truth)

bool inside_reference(real2 ref) {
    return !(ref.x < -0.5 || ref.y < -0.5 || ref.x > real(u_ref_size.x) - 0.5 || ref.y > real(u_ref_size.y) - 0.5);
}
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
#endif


#ifndef PIXEL_LOOP
#ifdef COMPUTE_PIXELS
void shade_sample(ivec2 at) {
#else
void main() {
#endif
    real xi, eta;
    real2 ref;
#if defined(MODE_FAST)
#ifdef COMPUTE_PIXELS
    uint t = texelFetch(u_visibility, at, 0).r;
    if (t == 0u) return;
    fast_triangle(int(t) - 1, g_uv, g_ref, g_xe, g_z, g_elem);
#endif
    // the perspective-correct interpolation of glsim.backends.cpu._fast in float32, at the
    // sample's exact pixel point q: barycentrics from edge functions relative to vertex 0
    vec2 q = FRAG_COORD / float(SS) - 0.5;
    vec2 a = g_uv[0], ab = g_uv[1] - a, ac = g_uv[2] - a, aq = q - a;
    float den = ab.x * ac.y - ab.y * ac.x;
    float l1 = (aq.x * ac.y - aq.y * ac.x) / den, l2 = (ab.x * aq.y - ab.y * aq.x) / den;
    vec3 w = vec3(1.0 - l1 - l2, l1, l2) / vec3(g_z[0], g_z[1], g_z[2]);
    float sw = w.x + w.y + w.z;
    float Z = 1.0 / sw;
    w *= Z;
    ref = real2(w.x * g_ref[0] + w.y * g_ref[1] + w.z * g_ref[2]);
    vec2 xe = w.x * g_xe[0] + w.y * g_xe[1] + w.z * g_xe[2];
    xi = xe.x;
    eta = xe.y;
    int elem = g_elem;
#ifndef COMPUTE_PIXELS   // (there FAST_VISIBILITY has left such samples out)
    if (ref.x < -0.5 || ref.y < -0.5 || ref.x > real(u_ref_size.x) - 0.5 || ref.y > real(u_ref_size.y) - 0.5) {
        atomicAdd(dropped_samples, 1u);  // counted for the warning (glsim.stages.view.warn_dropped)
        DROP;
    }
#endif
#ifdef FAST_VISIBILITY
    out_triangle = uint(g_tri + 1);
#endif
#else
    ivec2 pix = ivec2(FRAG_COORD) / SS;
#if defined(RESOLVE) || defined(FALLBACK) || !(defined(EARLY_TESTS) || defined(COMPUTE_PIXELS))
    // (the one-candidate pass needs no count where classify.frag's layer or classify.comp's list implies it)
    uint n = candidate_count(pix);
#endif
#if defined(RESOLVE)
    if (n < 2u || n > uint(CANDIDATES)) DROP;
#elif defined(FALLBACK)
    if (n <= uint(CANDIDATES) || n == LIST_DONE) DROP;
#elif !defined(EARLY_TESTS) && !defined(COMPUTE_PIXELS)
    if (n != 1u) DROP;
#endif
#ifdef APERTURE
    real2 px = aperture_sample(ivec2(FRAG_COORD));   // sensor.fill_factor < 1
    vec2 sample_px = vec2(px);
#else
    vec2 sample_px = FRAG_COORD / float(SS) - 0.5;  // this sample's pixel coordinates
    real2 px = real2(FRAG_COORD) / real(SS) - 0.5;
#endif
    real2 xn = real2(0.0);
#if defined(MODE_EXACT)
    if (!ray_at(u_rays, ivec2(FRAG_COORD), xn)) DROP;
#endif
    int elem = -1;
    real Z = 0.0;
#if defined(RESOLVE)
    bool dropped = false;
    real2 chosen_lo = real2(0.0);
    for (int k = 0; k < int(n); ++k) {
        int e = candidate(pix, k);
        if (!in_tight(e, sample_px, 0.0)) continue;
        real x, y, z;
        real2 r;
        bool ok;
        if (!map_sample(e, px, xn, x, y, r, z, ok)) continue;
        if (elem >= 0 && !(z < Z || (z == Z && e < elem))) continue;   // nearest, then lowest index
        if (!ok) {
            dropped = true;   // unless a farther owner maps inside the reference
            continue;
        }
        elem = e;
        xi = x; eta = y; ref = r; Z = z;
        chosen_lo = ref_lo;
    }
    ref_lo = chosen_lo;
    if (elem < 0) {
        if (dropped) atomicAdd(dropped_samples, 1u);  // counted for the warning (warn_dropped)
        DROP;
    }
#else
#if defined(FALLBACK)
    elem = v_elem;
#else
    elem = candidate(pix, 0);
#endif
    bool ok;
    if (!map_sample(elem, px, xn, xi, eta, ref, Z, ok)) DROP;
    if (!ok) {
        atomicAdd(dropped_samples, 1u);  // counted for the warning (warn_dropped)
        DROP;
    }
#endif
#ifndef COMPUTE_PIXELS
    gl_FragDepth = float(Z) / u_far;
#endif
#endif
#ifndef FAST_VISIBILITY
    float grey = sample_ref(ref);
#ifdef LIGHTING
    grey = combine(grey, light_at(elem, xi, eta));
#endif
    out_grey = grey;
#ifdef DEPTH_OUT
    out_depth = float(Z);
#endif
#ifdef TRUTH
#if defined(FP64)
    // float64 truth as float32 hi + lo, split with bit operations (hilo.glsl)
    vec4 ref_hl = split_double2(ref), xe_hl = split_double2(real2(xi, eta));
    out_map = vec4(ref_hl.xy, xe_hl.xy);
    out_extra = vec4(float(elem + 1), ref_hl.zw, 0.0);
#ifdef TRUTH_LO
    out_lo = xe_hl.zw;
#endif
#else
    out_map = vec4(vec2(ref), float(xi), float(eta));
#if defined(MODE_FAST)
    out_extra = vec4(float(elem + 1), 0.0, 0.0, 0.0);
#else
    out_extra = vec4(float(elem + 1), vec2(ref_lo), 0.0);   // REF_LOCAL's dropped part, else 0
#endif
#endif
#endif
#endif
#ifdef COMPUTE_PIXELS
    imageStore(u_out_grey, at, vec4(out_grey));
#ifdef TRUTH
    imageStore(u_out_map, at, out_map);
    imageStore(u_out_extra, at, out_extra);
#ifdef TRUTH_LO
    imageStore(u_out_lo, at, vec4(out_lo, 0.0, 0.0));
#endif
#endif
#ifdef DEPTH_OUT
    imageStore(u_out_depth, at, vec4(out_depth));
#endif
#endif
}
#ifdef COMPUTE_PIXELS
#ifdef MODE_FAST
void main() {   // every sample of the target (FAST_VISIBILITY's)
    ivec2 at = ivec2(gl_GlobalInvocationID.xy);
    if (all(lessThan(at, textureSize(u_visibility, 0)))) shade_sample(at);
}
#else
void main() {
#ifdef RESOLVE
    const uint layer = 1u;
#else
    const uint layer = 0u;
#endif
    // one invocation per sample of a listed pixel (a loop over them ran far slower on llvmpipe)
    uint i = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * uint(LIST_LOCAL) + gl_GlobalInvocationID.x;
    uint j = i / uint(SS * SS), k = i % uint(SS * SS);
    if (j >= layer_count[layer]) return;
    uint w = pixels[LIST_SLOT(layer, j)];
    shade_sample(ivec2(w & 0xFFFFu, w >> 16) * SS + ivec2(k % uint(SS), k / uint(SS)));
}
#endif
#endif
#endif
