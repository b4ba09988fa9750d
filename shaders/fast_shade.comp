// Pass 2 of mode fast in the compute pixel stage, second half: every sample of the target that
// fast_ids.frag gave a triangle, shaded from that triangle's record (fasttriangles.glsl) as
// fast.frag shades it.
#include "fast_sample.glsl"
#include "fasttriangles.glsl"
#include "shading.glsl"
#include "comp_targets.glsl"
#include "write_sample.glsl"

layout(local_size_x = 16, local_size_y = 8) in;

// the triangle of each sample (fast_ids.frag's target; 0: none)
layout(binding = SAMPLER_VISIBILITY) uniform usampler2D u_visibility;

void main() {
    ivec2 at = ivec2(gl_GlobalInvocationID.xy);
    if (!all(lessThan(at, textureSize(u_visibility, 0)))) return;
    uint t = texelFetch(u_visibility, at, 0).r;
    if (t == 0u) return;
    vec2 uv[3], ref3[3], xe3[3];
    float z[3];
    int elem;
    fast_triangle(int(t) - 1, uv, ref3, xe3, z, elem);
    real2 ref;
    real xi, eta;
    float Z;
    fast_sample(at, uv, ref3, xe3, z, ref, xi, eta, Z);
    write_sample(shade_sample(elem, xi, eta, ref), elem, xi, eta, ref, Z, real2(0.0));
    store_targets(at);
}
