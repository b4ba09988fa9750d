// Lens PSF (glsim/effects/psf.py; psf.frag, psf.comp): out(p) = sum over d of k(d) * src(p - d), |d| <= RADIUS,
// pixels beyond the image clamped to its edge. PSF_ROWS then PSF_COLUMNS: the two 1-D passes
// of a separable kernel (u_taps, 2 RADIUS + 1 weights); PSF_2D: the whole kernel, an R32F
// texture of (2 RADIUS + 1)^2 texels (texel (i, j): offset (i - RADIUS, j - RADIUS)).
#define TAPS (2 * RADIUS + 1)

layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
#ifdef PSF_2D
layout(binding = SAMPLER_KERNEL) uniform sampler2D u_kernel;
#else
uniform float u_taps[TAPS];
#endif

float psf(ivec2 p) {
    ivec2 last = textureSize(u_src, 0) - 1;
    float acc = 0.0;
#if defined(PSF_2D)
    for (int j = 0; j < TAPS; ++j)
        for (int i = 0; i < TAPS; ++i)
            acc += texelFetch(u_kernel, ivec2(i, j), 0).r
                   * texelFetch(u_src, clamp(p + RADIUS - ivec2(i, j), ivec2(0), last), 0).r;
#else
#if defined(PSF_ROWS)
    ivec2 step = ivec2(1, 0);
#else
    ivec2 step = ivec2(0, 1);
#endif
    for (int i = 0; i < TAPS; ++i)
        acc += u_taps[i] * texelFetch(u_src, clamp(p + (RADIUS - i) * step, ivec2(0), last), 0).r;
#endif
    return acc;
}
