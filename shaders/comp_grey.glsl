// A compute pass (comp_pass.glsl) that writes one float per pixel, into an R32F image:
// PASS_WRITE(value).
#include "comp_pass.glsl"
layout(r32f, binding = IMAGE_PASS_OUT) uniform writeonly image2D u_out;
#define PASS_WRITE(v) imageStore(u_out, PASS_PIXEL, vec4(v))
