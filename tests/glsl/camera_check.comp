// Runs shaders/camera.glsl on a batch of points: projection of camera-frame points and
// undistortion of pixels, for comparison with OpenCV in tests/test_gl_programs.py.
#include "camera.glsl"

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Points { real pts[]; };    // X, Y, Z per point
layout(std430, binding = 1) readonly buffer Pixels { real pix[]; };    // u, v per pixel
layout(std430, binding = 2) writeonly buffer Proj { real proj[]; };    // u, v, ok
layout(std430, binding = 3) writeonly buffer Undist { real und[]; };   // xn, yn, ok

uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;
uniform int u_count;

void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= u_count) return;
    real2 uv;
    bool ok = project_camera_frame(real3(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2]), u_intr, u_dist, u_valid_r2, uv);
    proj[3 * i] = uv.x;
    proj[3 * i + 1] = uv.y;
    proj[3 * i + 2] = ok ? 1.0 : 0.0;
    real2 xn;
    ok = undistort(pixel_to_normalized(real2(pix[2 * i], pix[2 * i + 1]), u_intr), u_dist, u_valid_r2, xn);
    und[3 * i] = xn.x;
    und[3 * i + 1] = xn.y;
    und[3 * i + 2] = ok ? 1.0 : 0.0;
}
