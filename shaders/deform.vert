// Modes fast and q4: each element's corners projected with lens distortion (vertex stage).
#include "camera.glsl"

in vec3 in_pos;      // deformed corner, camera frame (mm)
in vec2 in_ref;      // reference-image coordinates of the corner (px)
in vec2 in_xe;       // the corner's (xi, eta)
in int in_elem;      // element index

uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;
uniform vec2 u_size;  // image size W, H (px)
uniform float u_far;  // depth range (mm)

out vec2 v_ref;
out vec2 v_xe;
out float v_depth;   // camera-frame Z, perspective-correct
flat out int v_elem;

void main() {
    real2 uv;
    project_camera_frame(real3(in_pos), u_intr, u_dist, u_valid_r2, uv);
    // pixel centre u lands on NDC (u + 0.5) / W * 2 - 1; rows are not flipped, so framebuffer
    // row v (counted from GL's bottom) is image row v (counted from the top)
    vec2 ndc = (vec2(uv) + 0.5) / u_size * 2.0 - 1.0;
    float w = in_pos.z;
    gl_Position = vec4(ndc * w, (2.0 * w / u_far - 1.0) * w, w);  // w = Z: perspective-correct
    v_ref = in_ref;
    v_xe = in_xe;
    v_depth = in_pos.z;
    v_elem = in_elem;
}
