// Quantisation (quantize.glsl) as a compute pass, into an unsigned integer image of format
// OUT_FORMAT (r8ui, r16ui).
#include "comp_pass.glsl"
#include "quantize.glsl"
layout(OUT_FORMAT, binding = IMAGE_PASS_OUT) uniform writeonly uimage2D u_out;

void main() {
    if (PASS_OUTSIDE) return;
    imageStore(u_out, PASS_PIXEL, uvec4(quantized(PASS_PIXEL)));
}
