// Depth-of-field blur, one full-screen pass (the GLSL twin of glsim/effects/dof.py):
//   BLUR_HORIZONTAL, then BLUR_VERTICAL on its output: separable truncated Gaussian
//     (blur_separable), window |k| <= ceil(3 sigma), renormalised, clipped at the border;
//   BLUR_DISK: 2-D gather with the antialiased aperture weight clamp(r + 0.5 - |d|, 0, 1)
//     (blur_disk), window |dx|, |dy| <= ceil(r).
// Gather: the kernel size comes from the *output* pixel's depth. sigma (or r) = 0 copies the
// source texel exactly. MAX_RADIUS (define) bounds the loop: >= ceil(3 sigma_max) or ceil(r_max);
// a pixel needing more is cut to MAX_RADIUS.
#include "dof.glsl"

uniform sampler2D u_src;    // R32F grey
uniform sampler2D u_depth;  // R32F camera-frame depth Z (mm) per pixel, 0 = no surface

out float out_grey;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_src, 0);
    float Z = texelFetch(u_depth, p, 0).r;
#if defined(BLUR_HORIZONTAL) || defined(BLUR_VERTICAL)
    float sigma = blur_sigma(Z);
    if (sigma <= 0.0) {
        out_grey = texelFetch(u_src, p, 0).r;
        return;
    }
    int R = min(int(ceil(3.0 * sigma)), MAX_RADIUS);
#ifdef BLUR_HORIZONTAL
    ivec2 axis = ivec2(1, 0);
#else
    ivec2 axis = ivec2(0, 1);
#endif
    float c = -0.5 / (sigma * sigma);
    float acc = 0.0;
    float wsum = 0.0;
    for (int k = -R; k <= R; ++k) {
        ivec2 q = p + k * axis;
        if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
        float w = exp(float(k * k) * c);
        acc += w * texelFetch(u_src, q, 0).r;
        wsum += w;
    }
    out_grey = acc / wsum;
#elif defined(BLUR_DISK)
    float r = blur_radius(Z);
    if (r <= 0.0) {
        out_grey = texelFetch(u_src, p, 0).r;
        return;
    }
    int R = min(int(ceil(r)), MAX_RADIUS);
    float acc = 0.0;
    float wsum = 0.0;
    for (int dy = -R; dy <= R; ++dy) {
        for (int dx = -R; dx <= R; ++dx) {
            ivec2 q = p + ivec2(dx, dy);
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) continue;
            float w = clamp(r + 0.5 - length(vec2(dx, dy)), 0.0, 1.0);
            acc += w * texelFetch(u_src, q, 0).r;
            wsum += w;
        }
    }
    out_grey = acc / wsum;
#else
#error "blur.frag: define BLUR_HORIZONTAL, BLUR_VERTICAL or BLUR_DISK"
#endif
}
