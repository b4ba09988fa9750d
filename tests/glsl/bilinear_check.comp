// Runs invert_closed of shaders/bilinear.glsl on a batch of 2-D quads and target points, for
// comparison with glsim.scene.bilinear.invert_closed in tests/test_gl_programs.py.
#include "bilinear.glsl"

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Quads { real quads[]; };   // 4 corners (x, y) per quad
layout(std430, binding = 1) readonly buffer Targets { real targets[]; };  // q (x, y) per quad
layout(std430, binding = 2) writeonly buffer Roots { real roots[]; };  // per root: xi, eta, ok

uniform int u_count;

void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= u_count) return;
    real2 p[4];
    for (int k = 0; k < 4; ++k) p[k] = real2(quads[8 * i + 2 * k], quads[8 * i + 2 * k + 1]);
    real xi[2], eta[2];
    bool ok[2];
    invert_closed(p, real2(targets[2 * i], targets[2 * i + 1]), xi, eta, ok);
    for (int k = 0; k < 2; ++k) {
        roots[6 * i + 3 * k] = xi[k];
        roots[6 * i + 3 * k + 1] = eta[k];
        roots[6 * i + 3 * k + 2] = ok[k] ? 1.0 : 0.0;
    }
}
