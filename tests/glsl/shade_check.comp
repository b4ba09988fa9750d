// Runs shaders/shade.glsl on a batch of points for comparison with glsim/effects/lighting.py in
// tests/test_shade.py: per point, phong(X, N) and combine(grey, phong(X, N)).
#include "shade.glsl"

layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Points { float pts[]; };    // X, Y, Z per point
layout(std430, binding = 1) readonly buffer Normals { float nrm[]; };   // Nx, Ny, Nz per point
layout(std430, binding = 2) readonly buffer Greys { float grey[]; };    // grey per point
layout(std430, binding = 3) writeonly buffer Out { float res[]; };      // I, combined

uniform int u_count;

void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= u_count) return;
    float I = phong(vec3(pts[3 * i], pts[3 * i + 1], pts[3 * i + 2]),
                    vec3(nrm[3 * i], nrm[3 * i + 1], nrm[3 * i + 2]));
    res[2 * i] = I;
    res[2 * i + 1] = combine(grey[i], I);
}
