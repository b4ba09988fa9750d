// Quantisation (quantize.glsl) as a fragment pass, into an unsigned integer target.
#include "frag_pass.glsl"
#include "quantize.glsl"
out uint out_q;

void main() {
    out_q = quantized(PASS_PIXEL);
}
