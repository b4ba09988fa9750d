// The double-path primitives of the shaders on a batch of inputs, written bit for bit, for
// comparison with their numpy twins (glsim.evaluation.check.fp64_probe, glsim check): hilo.glsl's
// split_double, camera.glsl's pixel_to_normalized, distort and normalized_to_pixel, bilinear.glsl's
// pinhole_corners and edge_functions_ray. Its own loops over local double arrays are written out
// (#pragma unroll), as the renderer's are: a variable index would round them to float32 on NVIDIA.
#include "camera.glsl"
#include "bilinear.glsl"
#include "hilo.glsl"

layout(local_size_x = 64) in;

// per item: x, uv (2), intr (5), P (4 × 3), q (2), k (12), xn (2) — 36 doubles
layout(std430, binding = 0) readonly buffer In { double inputs[]; };
// per item: split (hi, lo), xd (2), A (4 × 3), E (4), m (4 × 2), distort(xn) (2), its pixel (2) — 32 doubles
layout(std430, binding = 1) writeonly buffer Out { double outputs[]; };

uniform int u_count;

void main() {
    int i = int(gl_GlobalInvocationID.x);
    if (i >= u_count) return;
    int a = 36 * i, o = 32 * i;
    vec2 hl = split_double(inputs[a]);
    outputs[o] = double(hl.x);
    outputs[o + 1] = double(hl.y);
    double intr[5];
    #pragma unroll
    for (int k = 0; k < 5; ++k) intr[k] = inputs[a + 3 + k];
    dvec2 xd = pixel_to_normalized(dvec2(inputs[a + 1], inputs[a + 2]), intr);
    outputs[o + 2] = xd.x;
    outputs[o + 3] = xd.y;
    dvec3 P[4], A[4];
    #pragma unroll
    for (int k = 0; k < 4; ++k) P[k] = dvec3(inputs[a + 8 + 3 * k], inputs[a + 9 + 3 * k], inputs[a + 10 + 3 * k]);
    pinhole_corners(P, intr, A);
    double E[4];
    dvec2 m[4];
    edge_functions_ray(A, dvec2(inputs[a + 20], inputs[a + 21]), E, m);
    #pragma unroll
    for (int k = 0; k < 4; ++k) {
        outputs[o + 4 + 3 * k] = A[k].x;
        outputs[o + 5 + 3 * k] = A[k].y;
        outputs[o + 6 + 3 * k] = A[k].z;
        outputs[o + 16 + k] = E[k];
        outputs[o + 20 + 2 * k] = m[k].x;
        outputs[o + 21 + 2 * k] = m[k].y;
    }
    double k[12];
    #pragma unroll
    for (int c = 0; c < 12; ++c) k[c] = inputs[a + 22 + c];
    dvec2 d = distort(dvec2(inputs[a + 34], inputs[a + 35]), k);
    dvec2 uv = normalized_to_pixel(d, intr);
    outputs[o + 28] = d.x;
    outputs[o + 29] = d.y;
    outputs[o + 30] = uv.x;
    outputs[o + 31] = uv.y;
}
