// The grey image as the camera writes it, bit for bit glsim.io.images.quantize: grey levels of
// full scale × (2^bits − 1), rounded half to even, clipped to 0 … 2^bits − 1. Needs FP64: a
// float32 times 2^bits − 1 (≤ 65535) is exact in float64, so the rounding sees the exact product.
layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
uniform double u_top;   // 2^bits − 1

out uint out_q;

void main() {
    precise double v = double(texelFetch(u_src, ivec2(gl_FragCoord.xy), 0).r) * u_top;
    out_q = uint(clamp(roundEven(v), 0.0lf, u_top));
}
