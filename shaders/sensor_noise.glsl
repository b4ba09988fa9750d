// Sensor noise (noise.frag, noise.comp): out = I + noise_sigma(I) * z, z the standard normal of
// the flat pixel index v * W + u and the image's seed. Not clipped (quantisation clips).
#include "noise.glsl"

layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
uniform uint u_seed;
uniform int u_width;

float noisy(ivec2 p) {   // (framebuffer row v = image row v: no flip)
    float I = texelFetch(u_src, p, 0).r;
    uint index = uint(p.y) * uint(u_width) + uint(p.x);
    return I + noise_sigma(I) * standard_normal(index, u_seed);
}
