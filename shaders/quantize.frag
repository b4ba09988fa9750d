// The grey image as the camera writes it, bit for bit glsim.io.images.quantize: grey levels of
// full scale × (2^bits − 1), rounded half to even, clipped to 0 … 2^bits − 1. Needs FP64: a
// float32 times 2^bits − 1 (≤ 65535) is exact in float64, so the rounding sees the exact product.
// Either pixel stage (pixelpass.glsl; quantize.comp).
#include "pixelpass.glsl"
layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
uniform double u_top;   // 2^bits − 1

#ifdef COMPUTE_PIXELS
layout(OUT_FORMAT, binding = IMAGE_PASS_OUT) uniform writeonly uimage2D u_out;
#else
out uint out_q;
#endif

void main() {
    if (PASS_OUTSIDE) return;
    precise double v = double(texelFetch(u_src, PASS_PIXEL, 0).r) * u_top;
    uint q = uint(clamp(roundEven(v), 0.0lf, u_top));
#ifdef COMPUTE_PIXELS
    imageStore(u_out, PASS_PIXEL, uvec4(q));
#else
    out_q = q;
#endif
}
