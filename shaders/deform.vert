// Mode fast: each element's corners projected with lens distortion (vertex stage), from the
// mesh uploaded once (view.glsl) and the step's nodes; elements that do not project are
// dropped (all their vertices on one point). No vertex attributes: vertex 4 e + i is corner i
// of element e (index buffer: triangles (0, 1, 2), (0, 2, 3)). Corner 1, drawn once per
// element, records the element's problems for the warnings.
#include "camera.glsl"
#include "view.glsl"

layout(std430, binding = BINDING_REF_UV) readonly buffer RefUV { real ref_uv[]; };  // per node (px)

uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;
uniform vec2 u_size;  // image size W, H (px)
uniform float u_far;  // depth range (mm)

out vec2 v_uv;      // the projected vertex (px), for fast.geom
out vec2 v_ref;
out vec2 v_xe;
out float v_depth;   // camera-frame Z
flat out int v_elem;

const vec2 CORNER_XE[4] = vec2[4](vec2(-1.0, -1.0), vec2(1.0, -1.0), vec2(1.0, 1.0), vec2(-1.0, 1.0));

void main() {
    int e = gl_VertexID >> 2, c = gl_VertexID & 3;
    real3 P[4];
    element_corners(e, P);
    bool projectable = corners_projectable(P, u_valid_r2);
    if (c == 1) record_flags(e, P, projectable, corners_behind(P));
    v_elem = e;
    v_xe = CORNER_XE[c];
    if (!projectable) {
        gl_Position = vec4(-2.0, -2.0, -2.0, 1.0);
        v_uv = vec2(0.0);
        v_ref = vec2(0.0);
        v_depth = 0.0;
        return;
    }
    real2 uv;
    project_camera_frame(P[c], u_intr, u_dist, u_valid_r2, uv);
    // pixel centre u lands on NDC (u + 0.5) / W * 2 - 1; rows are not flipped, so framebuffer
    // row v (counted from GL's bottom) is image row v (counted from the top)
    v_uv = vec2(uv);
    vec2 ndc = (v_uv + 0.5) / u_size * 2.0 - 1.0;
    float w = float(P[c].z);
    gl_Position = vec4(ndc * w, (2.0 * w / u_far - 1.0) * w, w);  // w = Z: perspective-correct
    int n = quads[e][c];
    v_ref = vec2(ref_uv[2 * n], ref_uv[2 * n + 1]);
    v_depth = w;
}
