// Fixed-pattern noise (EMVA 1288; glsim/effects/noise.py fixed_pattern; fpn.frag, fpn.comp): out = I * (1 + u_prnu * z_p)
// + u_dsnu * z_d, z_p and z_d the standard normals of the flat pixel index v * W + u and the
// camera's seed on streams 2 (and 3) and 4 (and 5): the same maps at every load step.
#include "noise.glsl"

layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
uniform uint u_seed;
uniform int u_width;
uniform float u_prnu;   // relative gain sigma (prnu % / 100)
uniform float u_dsnu;   // offset sigma in full scale (dsnu DN / (2^bits - 1))

float fixed_pattern(ivec2 p) {
    float I = texelFetch(u_src, p, 0).r;
    uint index = uint(p.y) * uint(u_width) + uint(p.x);
    return I * (1.0 + u_prnu * standard_normal(index, u_seed, 2u)) + u_dsnu * standard_normal(index, u_seed, 4u);
}
