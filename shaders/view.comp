// Per-view element pass (modes exact and q4): from the mesh uploaded once and the step's nodes,
// each element's record for pass 2 (records.glsl), its conservative cover rectangle for exact.vert
// (glsim.stages.view.cover_rectangles) and its problems for the warnings. Compile-time:
// MODE_Q4 or MODE_EXACT, FP64, RECORD_LOCAL (with both: float32 records for CAMERA_LOCAL).
#define COVER
#include "camera.glsl"
#include "view.glsl"
#include "hilo.glsl"

layout(local_size_x = 64) in;

uniform int u_count;        // elements
uniform real u_valid_r2;

// exact: corners in the camera frame (12, mm); q4: distorted pixel corners (8) and depths Z (4)
layout(std430, binding = BINDING_ELEMENTS) writeonly buffer Elements { real elem_data[]; };
layout(std430, binding = BINDING_COVER) writeonly buffer Cover { vec2 cover[]; };  // 4 corners per element (px)
layout(std430, binding = BINDING_TIGHT) writeonly buffer Tight { vec4 tight[]; };  // 2 per element (candidates.glsl)
#ifdef RECORD_LOCAL
// float32 exact on a driver with float64 (sample_map.glsl's CAMERA_LOCAL), 32 float32 per
// element: the corners (12, rounded), the corners relative to their centre C (12), C.z, 0,
// and C.xy / C.z as hi (2) + lo (2), 0, 0 — made here in float64
layout(std430, binding = BINDING_LOCAL) writeonly buffer Local { float elem_local[]; };
#endif

void main() {
    int e = int((gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * gl_WorkGroupSize.x
                + gl_LocalInvocationID.x);
    if (e >= u_count) return;
    real3 P[4];
    element_corners(e, P);
    bool projectable = corners_projectable(P, u_valid_r2);
    bool behind = corners_behind(P);
    record_flags(e, P, projectable, behind);
    int b = 12 * e;
#if defined(MODE_Q4)
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        real2 uv;
        project_camera_frame(P[i], u_intr, u_dist, u_valid_r2, uv);
        elem_data[b + 2 * i] = uv.x;
        elem_data[b + 2 * i + 1] = uv.y;
        elem_data[b + 8 + i] = P[i].z;
    }
    bool drawn = projectable && !behind;   // q4 draws only elements that project
#else
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        elem_data[b + 3 * i] = P[i].x;
        elem_data[b + 3 * i + 1] = P[i].y;
        elem_data[b + 3 * i + 2] = P[i].z;
    }
    bool drawn = !behind;
#ifdef RECORD_LOCAL
    real3 C = 0.25 * (P[0] + P[1] + P[2] + P[3]);
    real2 xc = C.z > 0.0 ? C.xy / C.z : real2(0.0);
    vec4 xc_hl = split_double2(xc);   // hilo.glsl (RECORD_LOCAL is an FP64 build)
    int l = 32 * e;
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        #pragma unroll
        for (int k = 0; k < 3; ++k) {
            elem_local[l + 3 * i + k] = float(P[i][k]);
            elem_local[l + 12 + 3 * i + k] = float(P[i][k] - C[k]);
        }
    }
    vec4 tail[2] = vec4[2](vec4(float(C.z > 0.0 ? C.z : 0.0), 0.0, xc_hl.xy), vec4(xc_hl.zw, 0.0, 0.0));
    for (int k = 0; k < 4; ++k) {
        elem_local[l + 24 + k] = tail[0][k];
        elem_local[l + 28 + k] = tail[1][k];
    }
#endif
#endif
    vec2 rect[4];
    vec4 t[2];
    if (drawn) {
        if (projectable) projectable_cover(P, rect, t);
        else drawn = unprojectable_cover(P, rect, t);
    }
    if (!drawn) {
        rect = vec2[4](vec2(-16.0), vec2(-16.0), vec2(-16.0), vec2(-16.0));  // zero area, culled
        t = vec4[2](vec4(1.0, 0.0, 1.0, -1.0), vec4(1.0, -1.0, 0.0, 0.0));   // empty
    }
    for (int i = 0; i < 4; ++i) cover[4 * e + i] = rect[i];
    tight[2 * e] = t[0];
    tight[2 * e + 1] = t[1];
}
