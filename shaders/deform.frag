// Grey value of each sample: map it to the reference image and interpolate (paper §2.1).
// Compile-time choices: MODE_FAST | MODE_Q4 | MODE_EXACT, INTERP_*, SS (samples per pixel
// per axis), FP64 (double arithmetic), TRUTH (also write the truth maps), LIGHTING (Phong,
// shade.glsl), DEPTH_OUT (write camera-frame depth Z at DEPTH_LOCATION, for depth of field).
#include "camera.glsl"
#include "interp.glsl"
#include "bilinear.glsl"
#ifdef LIGHTING
#include "shade.glsl"
// per element: corners in the camera frame (12) and corner normals (12), float32
layout(std430, binding = 1) readonly buffer Shading { float shade_data[]; };
#endif

uniform vec2 u_ref_size;  // reference image W, H (px)
uniform float u_far;      // depth range (mm): gl_FragDepth = Z / u_far

#if defined(MODE_FAST)
in vec2 v_ref;
in vec2 v_xe;
in float v_depth;
#else
// Per-view element records written by view.comp, float64 or float32 as `real`: exact: corners
// in the camera frame (12); q4: distorted pixel corners (8) and depths Z (4).
layout(std430, binding = 0) readonly buffer Elements { real elem_data[]; };
// the mesh, uploaded once per renderer (glsim.backends.gl.backend): connectivity and, per
// node, reference-image coordinates (q4) or the undeformed position in the reference camera's
// frame (exact)
layout(std430, binding = 5) readonly buffer Quads { ivec4 quads[]; };
#if defined(MODE_Q4)
layout(std430, binding = 7) readonly buffer RefUV { real ref_uv[]; };
#else
layout(std430, binding = 8) readonly buffer RefXr { real ref_xr[]; };
#endif
#endif
flat in int v_elem;
// samples that hit the specimen but map outside the reference image (reset before each pass)
layout(std430, binding = 4) buffer Dropped { uint dropped_samples; };

#if defined(MODE_EXACT)
uniform sampler2D u_rays;   // rays.frag: per-sample undistorted normalized coordinates (hi, lo)
uniform real u_ref_intr[5];
uniform real u_ref_dist[12];
uniform real u_ref_valid_r2;
#endif

layout(location = 0) out float out_grey;
#ifdef TRUTH
layout(location = 1) out vec4 out_map;     // ref u, ref v, xi, eta (float32)
layout(location = 2) out vec4 out_extra;   // element + 1, ref u and v rounding residuals
#endif
#ifdef DEPTH_OUT
layout(location = DEPTH_LOCATION) out float out_depth;  // camera-frame Z (mm)
#endif

#ifdef LIGHTING
// Phong intensity at (xi, eta) of element e: surface point and interpolated unit normal.
float light_at(int e, real xi, real eta) {
    vec4 w = vec4(shape_functions(xi, eta));
    vec3 X = vec3(0.0), N = vec3(0.0);
    for (int i = 0; i < 4; ++i) {
        int b = e * 24 + 3 * i;
        X += w[i] * vec3(shade_data[b], shade_data[b + 1], shade_data[b + 2]);
        N += w[i] * vec3(shade_data[b + 12], shade_data[b + 13], shade_data[b + 14]);
    }
    float n = length(N);
    return phong(X, n > 0.0 ? N / n : vec3(0.0));
}
#endif

void main() {
    real xi, eta;
    real2 ref;
#if defined(MODE_FAST)
    ref = real2(v_ref);
    xi = v_xe.x;
    eta = v_xe.y;
    float Z = v_depth;
#else
#if defined(MODE_Q4)
    real2 px = real2(gl_FragCoord.xy) / real(SS) - 0.5;  // this sample's pixel coordinates
    int b = v_elem * 12;
    real2 p[4];
    for (int i = 0; i < 4; ++i) p[i] = real2(elem_data[b + 2 * i], elem_data[b + 2 * i + 1]);
    // the cover rectangle (exact.vert) is padded; the shared tie rule decides coverage
    if (!invert_newton(p, px, xi, eta) || !in_range(xi, eta)) discard;
    if (near_edge(xi, eta)) {
        real E[4];
        real2 m[4];
        edge_functions_2d(p, px, E, m);
        if (!owned(xi, eta, E, m, orientation_2d(p, xi, eta))) discard;
    }
    ivec4 q = quads[v_elem];
    real2 r[4];
    for (int i = 0; i < 4; ++i) r[i] = real2(ref_uv[2 * q[i]], ref_uv[2 * q[i] + 1]);
    ref = bilinear2(r, xi, eta);
    real4 N = shape_functions(xi, eta);
    real Z = dot(N, real4(elem_data[b + 8], elem_data[b + 9], elem_data[b + 10], elem_data[b + 11]));
#else
    int b = v_elem * 12;
    real3 P[4];
    for (int i = 0; i < 4; ++i) P[i] = real3(elem_data[b + 3 * i], elem_data[b + 3 * i + 1], elem_data[b + 3 * i + 2]);
    vec4 ray = texelFetch(u_rays, ivec2(gl_FragCoord.xy), 0);
    if (ray.x >= 1e30) discard;  // rays.frag's NO_RAY
    real2 xn = real2(ray.xy) + real2(ray.zw);
    real Z;
    if (!intersect_ray_patch(P, xn, xi, eta, Z)) discard;
    ivec4 q = quads[v_elem];
    real3 R[4];  // undeformed corners in the reference camera's frame (mm)
    for (int i = 0; i < 4; ++i) R[i] = real3(ref_xr[3 * q[i]], ref_xr[3 * q[i] + 1], ref_xr[3 * q[i] + 2]);
    if (!project_camera_frame(bilinear3(R, xi, eta), u_ref_intr, u_ref_dist, u_ref_valid_r2, ref)) {
        atomicAdd(dropped_samples, 1u);
        discard;
    }
#endif
    gl_FragDepth = float(Z) / u_far;
#endif
    if (ref.x < -0.5 || ref.y < -0.5 || ref.x > real(u_ref_size.x) - 0.5 || ref.y > real(u_ref_size.y) - 0.5) {
        atomicAdd(dropped_samples, 1u);  // counted for the warning (glsim.stages.view.warn_dropped)
        discard;
    }
    float grey = sample_ref(ref);
#ifdef LIGHTING
    grey = combine(grey, light_at(v_elem, xi, eta));
#endif
    out_grey = grey;
#ifdef DEPTH_OUT
    out_depth = float(Z);
#endif
#ifdef TRUTH
    vec2 ref32 = vec2(ref);
    out_map = vec4(ref32, float(xi), float(eta));
    out_extra = vec4(float(v_elem + 1), vec2(ref - real2(ref32)), 0.0);
#endif
}
