// Reference-image interpolation: the GLSL twin of glsim/stages/interp.py (same kernels, tap order
// and index clamping). Needs the precision macros (real, real2) and exactly one of
// INTERP_LINEAR, INTERP_CUBIC, INTERP_BSPLINE3, INTERP_BSPLINE5 defined.
// The position is split in real precision (integer part exact in double); the kernel weights
// and the sum are float: the fractional offset in float errs by < 6e-8 px, and the sum has
// float32 precision anyway (the coefficients are float32 texels).

#ifdef INTERP_PROCEDURAL
#include "procedural.glsl"
#else

// Mirror padding of the coefficient image, px per side; keep in sync with glsim.stages.interp.PAD.
#define REF_PAD 4

// Padded coefficient image (glsim.stages.interp.prepare) as 2×2 blocks (RGBA32F,
// glsim.backends.gl.backend.pack_pairs): texel (i, j) holds the coefficients at padded columns
// i, i + 1 of row j (r, g) and of row j + 1 (b, a), the last column and row repeated, so one
// fetch reads four taps (the same values and sums as four single fetches).
layout(binding = SAMPLER_REF) uniform sampler2D u_ref;

// ref_weights(t, w): per-axis weights at fractional offset t in [0, 1); tap k multiplies
// the coefficient at floor(x) + REF_FIRST + k.
#if defined(INTERP_LINEAR)
#define REF_TAPS 2
#define REF_FIRST 0
void ref_weights(float t, out float w[REF_TAPS]) {
    w[0] = 1.0 - t;
    w[1] = t;
}
#elif defined(INTERP_CUBIC)
// Keys (1981) cubic convolution, a = -0.5.
#define REF_TAPS 4
#define REF_FIRST (-1)
void ref_weights(float t, out float w[REF_TAPS]) {
    w[0] = t * (-1.0 + t * (2.0 - t)) * 0.5;
    w[1] = (2.0 + t * t * (-5.0 + 3.0 * t)) * 0.5;
    w[2] = t * (1.0 + t * (4.0 - 3.0 * t)) * 0.5;
    w[3] = t * t * (t - 1.0) * 0.5;
}
#elif defined(INTERP_BSPLINE3)
#define REF_TAPS 4
#define REF_FIRST (-1)
void ref_weights(float t, out float w[REF_TAPS]) {
    float s = 1.0 - t;
    w[0] = s * s * s / 6.0;
    w[1] = (4.0 + t * t * (-6.0 + 3.0 * t)) / 6.0;
    w[2] = (1.0 + t * (3.0 + t * (3.0 - 3.0 * t))) / 6.0;
    w[3] = t * t * t / 6.0;
}
#elif defined(INTERP_BSPLINE5)
#define REF_TAPS 6
#define REF_FIRST (-2)
void ref_weights(float t, out float w[REF_TAPS]) {
    float s = 1.0 - t;
    float s2 = s * s;
    float t2 = t * t;
    w[0] = s2 * s2 * s / 120.0;
    w[1] = (26.0 + t * (-50.0 + t * (20.0 + t * (20.0 + t * (-20.0 + 5.0 * t))))) / 120.0;
    w[2] = (66.0 + t2 * (-60.0 + t2 * (30.0 - 10.0 * t))) / 120.0;
    w[3] = (26.0 + t * (50.0 + t * (20.0 + t * (-20.0 + t * (-20.0 + 10.0 * t))))) / 120.0;
    w[4] = (1.0 + t * (5.0 + t * (10.0 + t * (10.0 + t * (5.0 - 5.0 * t))))) / 120.0;
    w[5] = t2 * t2 * t / 120.0;
}
#else
#error "interp.glsl: define one of INTERP_LINEAR, INTERP_CUBIC, INTERP_BSPLINE3, INTERP_BSPLINE5"
#endif

// Interpolated grey level at uv = (column, row) in unpadded reference-image pixels.
// Taps beyond the padded texture read its edge texels.
float sample_ref(real2 uv) {
    real2 f = floor(uv);
    vec2 t = vec2(uv - f);
    float wx[REF_TAPS];
    float wy[REF_TAPS];
    ref_weights(t.x, wx);
    ref_weights(t.y, wy);
    ivec2 size = textureSize(u_ref, 0);
    // Clamp before the int conversion (undefined out of range); a first tap at
    // -REF_TAPS or beyond reads only edge texels anyway.
    ivec2 base = ivec2(clamp(f + real(REF_PAD + REF_FIRST), real2(-REF_TAPS), real2(size)));
    // (REF_TAPS is even; the first tap of a sampled point lies inside the padded image, so the
    // block's clamped neighbours equal the clamped taps)
    float acc = 0.0;
    for (int j = 0; j < REF_TAPS; j += 2) {
        int row = clamp(base.y + j, 0, size.y - 1);
        float s0 = 0.0, s1 = 0.0;
        for (int i = 0; i < REF_TAPS; i += 2) {
            vec4 q = texelFetch(u_ref, ivec2(clamp(base.x + i, 0, size.x - 1), row), 0);
            s0 += wx[i] * q.r;
            s0 += wx[i + 1] * q.g;
            s1 += wx[i] * q.b;
            s1 += wx[i + 1] * q.a;
        }
        acc += wy[j] * s0;
        acc += wy[j + 1] * s1;
    }
    return acc;
}
#endif
