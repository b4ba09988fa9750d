// The grey image as the camera writes it, bit for bit glsim.io.images.quantize: grey levels of
// full scale × (2^bits − 1), rounded half to even, clipped to 0 … 2^bits − 1 (quantize.frag,
// quantize.comp). Needs FP64: a float32 times 2^bits − 1 (≤ 65535) is exact in float64, so the
// rounding sees the exact product.
layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
uniform double u_top;   // 2^bits − 1

uint quantized(ivec2 p) {
    precise double v = double(texelFetch(u_src, p, 0).r) * u_top;
    return uint(clamp(roundEven(v), 0.0lf, u_top));
}
