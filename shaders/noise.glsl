// Camera sensor noise: the GLSL twin of glsim/effects/noise.py (same names and steps).
// A counter-based generator (PCG hash, uint arithmetic wraps as numpy's uint32), so GL and
// the numpy oracle draw the same uniforms bit for bit; only float32 log/sqrt/cos differ.
// Pick the model with one of NOISE_GAUSSIAN, NOISE_HETEROSCEDASTIC, NOISE_POISSON_GAUSSIAN.

uint pcg_hash(uint x) {
    uint state = x * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Uniform in (0, 1]: the top 24 bits of the hash, ((h >> 8) + 1) / 2^24 (exact in float).
float uniform01(uint index, uint seed, uint stream) {
    uint key = pcg_hash(seed ^ pcg_hash(stream));
    uint h = pcg_hash(pcg_hash(index) ^ key);
    return float((h >> 8u) + 1u) * (1.0 / 16777216.0);
}

// -log(u) for u in (0, 1] to float32 precision relative to its value. GLSL allows log an
// absolute error of 2^-21 in [0.5, 2] (llvmpipe has it), which sqrt(-2 log u1) would blow up
// as u1 -> 1 (5 % of z at z ~ 1e-3). For u >= 0.5: log u = 2 atanh(s), s = (u - 1)/(u + 1),
// |s| <= 1/3, summed to s^15 (truncation < 4e-9 relative); 1 - u is exact (Sterbenz).
float neg_log_unit(float u) {
    if (u < 0.5) return -log(u);
    float m = 1.0 - u;
    float s = m / (2.0 - m);
    float s2 = s * s;
    float p = 1.0 / 15.0;
    p = p * s2 + 1.0 / 13.0;
    p = p * s2 + 1.0 / 11.0;
    p = p * s2 + 1.0 / 9.0;
    p = p * s2 + 1.0 / 7.0;
    p = p * s2 + 1.0 / 5.0;
    p = p * s2 + 1.0 / 3.0;
    p = p * s2 + 1.0;
    return 2.0 * s * p;
}

// Standard normal by Box-Muller (cosine branch) from streams `stream` and `stream + 1`; u1 > 0,
// so log never sees 0. cos(2 pi u2) = -cos(2 pi (u2 - 1/2)): u2 - 1/2 is exact and the angle
// stays in [-pi, pi].
float standard_normal(uint index, uint seed, uint stream) {
    float u1 = uniform01(index, seed, stream);
    float u2 = uniform01(index, seed, stream + 1u);
    return -sqrt(2.0 * neg_log_unit(u1)) * cos(6.283185307179586 * (u2 - 0.5));
}

// The temporal noise's normal: streams 0 and 1.
float standard_normal(uint index, uint seed) { return standard_normal(index, seed, 0u); }

// Noise standard deviation in full-scale units at grey level I (full scale).
#if defined(NOISE_GAUSSIAN)
uniform float u_noise_sigma;  // full-scale units (sigma % of 2^bits levels, over 2^bits - 1)
float noise_sigma(float I) { return u_noise_sigma; }
#elif defined(NOISE_HETEROSCEDASTIC)
layout(binding = SAMPLER_VARIANCE) uniform sampler2D u_variance;  // R32F: variance (DN^2) at DN n in texel (n % width, n / width)
uniform float u_dn_max;        // 2^bits - 1
float variance_at(int n) {
    int w = textureSize(u_variance, 0).x;
    return texelFetch(u_variance, ivec2(n % w, n / w), 0).r;
}
float noise_sigma(float I) {
    float x = clamp(I * u_dn_max, 0.0, u_dn_max);
    int n = int(floor(x));
    float f = x - float(n);
    int top = int(u_dn_max);
    float v = mix(variance_at(n), variance_at(min(n + 1, top)), f);
    return sqrt(max(v, 0.0)) / u_dn_max;
}
#elif defined(NOISE_POISSON_GAUSSIAN)
uniform float u_full_well;   // electrons at full scale
uniform float u_read_noise;  // electrons rms
// Shot noise by its Gaussian approximation: variance e + read^2 (e-^2), exact in variance.
float noise_sigma(float I) {
    float e = max(I, 0.0) * u_full_well;
    return sqrt(e + u_read_noise * u_read_noise) / u_full_well;
}
#endif
