// Depth-of-field blur, one full-screen pass (the GLSL twin of glsim/effects/dof.py): blur.frag,
// blur.comp. One define chooses the pass; the scheme (optics.scheme) chooses the passes:
//   separable:  BLUR_HORIZONTAL, then BLUR_VERTICAL on its output (blur_separable): a 1-D
//               gather with the sigma of the pixel written; exact only where sigma is constant;
//   hybrid:     BLUR_HORIZONTAL, then BLUR_HYBRID (blur_hybrid): the vertical 1-D gather where
//               sigma is constant over the column window (the separable pair is exact there),
//               the 2-D gather of the unblurred image elsewhere;
//   gather:     BLUR_GATHER (blur_exact): the 2-D gather itself;
//   expansion:  BLUR_ROWS, then BLUR_COLUMNS (row_moments, blur_expansion): each row's moments
//               in its own sigma, expanded to the output pixel's sigma and window;
//   disk:       BLUR_DISK (blur_disk): 2-D gather with the antialiased aperture weight
//               clamp(r + 0.5 - |d|, 0, 1), window |dx|, |dy| <= ceil(r).
// Gaussian window |dx|, |dy| <= ceil(3 sigma), weights exp(-(dx^2 + dy^2) / (2 sigma^2)),
// renormalised over the window clipped at the image border. Gather: the kernel comes from the
// *output* pixel's depth; sigma (or r) = 0 (in focus, background) copies the source texel.
// MAX_RADIUS (define) bounds the loops: >= ceil(3 sigma_max) or ceil(r_max); a pixel needing
// more is cut to MAX_RADIUS.
#include "dof.glsl"

layout(binding = SAMPLER_SRC) uniform sampler2D u_src;      // R32F grey (BLUR_VERTICAL, BLUR_HYBRID: BLUR_HORIZONTAL's output)
layout(binding = SAMPLER_DEPTH) uniform sampler2D u_depth;    // R32F camera-frame depth Z (mm) per pixel, 0 = no surface
layout(binding = SAMPLER_IMAGE) uniform sampler2D u_image;    // BLUR_HYBRID, BLUR_COLUMNS: the unblurred grey
layout(binding = SAMPLER_MOMENTS) uniform sampler2D u_moments;  // BLUR_COLUMNS: BLUR_ROWS's moments M0..M3
layout(binding = SAMPLER_ROWS) uniform sampler2D u_rows;     // BLUR_COLUMNS: BLUR_ROWS's (remainder factor, c, R, grey) per pixel
uniform float u_expansion_tol;

// ceil(3 sigma) as numpy's kernel_radius (in double in FP64 builds), cut to MAX_RADIUS
int window(real sigma) { return min(int(ceil(real(3.0) * sigma)), MAX_RADIUS); }

bool inside(ivec2 q, ivec2 size) { return all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, size)); }

// The 2-D Gaussian gather of ``img`` at p (weights g(dx) g(dy), clipped window, renormalised).
float gather_gauss(sampler2D img, ivec2 p, ivec2 size, float sigma, int R) {
    float c = -0.5 / (sigma * sigma);
    float g[2 * MAX_RADIUS + 1];
    for (int k = -R; k <= R; ++k) g[k + MAX_RADIUS] = exp(float(k * k) * c);
    int x0 = max(p.x - R, 0), x1 = min(p.x + R, size.x - 1);
    int y0 = max(p.y - R, 0), y1 = min(p.y + R, size.y - 1);
    float wx = 0.0, wy = 0.0, acc = 0.0;
    for (int x = x0; x <= x1; ++x) wx += g[x - p.x + MAX_RADIUS];
    for (int y = y0; y <= y1; ++y) {
        float row = 0.0;
        for (int x = x0; x <= x1; ++x) row += g[x - p.x + MAX_RADIUS] * texelFetch(img, ivec2(x, y), 0).r;
        float gy = g[y - p.y + MAX_RADIUS];
        acc += gy * row;
        wy += gy;
    }
    return acc / (wx * wy);
}

// This pixel's sigma (px, from its depth: numpy's in FP64 builds), as a float, and its window.
real pixel_sigma(ivec2 p, out float sigma, out int R) {
    real sigma_p = blur_sigma(real(texelFetch(u_depth, p, 0).r));
    sigma = float(sigma_p);
    R = window(sigma_p);
    return sigma_p;
}

// BLUR_HORIZONTAL (axis (1, 0)), BLUR_VERTICAL (axis (0, 1)): the 1-D gather along axis.
float blur_line(ivec2 p, ivec2 axis) {
    ivec2 size = textureSize(u_depth, 0);
    float sigma;
    int R;
    pixel_sigma(p, sigma, R);
    if (sigma <= 0.0) {
        return texelFetch(u_src, p, 0).r;
    }
    float c = -0.5 / (sigma * sigma);
    float acc = 0.0;
    float wsum = 0.0;
    for (int k = -R; k <= R; ++k) {
        ivec2 q = p + k * axis;
        if (!inside(q, size)) continue;
        float w = exp(float(k * k) * c);
        acc += w * texelFetch(u_src, q, 0).r;
        wsum += w;
    }
    return acc / wsum;
}

// BLUR_HYBRID
float blur_hybrid(ivec2 p) {
    ivec2 size = textureSize(u_depth, 0);
    float sigma;
    int R;
    real sigma_p = pixel_sigma(p, sigma, R);
    if (sigma <= 0.0) {
        return texelFetch(u_image, p, 0).r;
    }
    float c = -0.5 / (sigma * sigma);
    float acc = 0.0;
    float wsum = 0.0;
    for (int k = -R; k <= R; ++k) {
        ivec2 q = p + ivec2(0, k);
        if (!inside(q, size)) continue;
        // the min/max of sigma along the column: any other sigma, and the rows read were
        // blurred with another kernel
        if (blur_sigma(real(texelFetch(u_depth, q, 0).r)) != sigma_p) {
            return gather_gauss(u_image, p, size, sigma, R);
        }
        float w = exp(float(k * k) * c);
        acc += w * texelFetch(u_src, q, 0).r;
        wsum += w;
    }
    return acc / wsum;
}

#include "blur_expansion.glsl"

// BLUR_DISK
float blur_disk(ivec2 p) {
    ivec2 size = textureSize(u_depth, 0);
    real Z = real(texelFetch(u_depth, p, 0).r);
    real r_p = blur_radius(Z);
    float r = float(r_p);
    if (r <= 0.0) {
        return texelFetch(u_src, p, 0).r;
    }
    int R = min(int(ceil(r_p)), MAX_RADIUS);
    float acc = 0.0;
    float wsum = 0.0;
    for (int dy = -R; dy <= R; ++dy) {
        for (int dx = -R; dx <= R; ++dx) {
            ivec2 q = p + ivec2(dx, dy);
            if (!inside(q, size)) continue;
            float w = clamp(r + 0.5 - length(vec2(dx, dy)), 0.0, 1.0);
            acc += w * texelFetch(u_src, q, 0).r;
            wsum += w;
        }
    }
    return acc / wsum;
}

#ifndef BLUR_ROWS
// The pass the define names (BLUR_ROWS writes two values: blur_rows).
float blur(ivec2 p) {
#if defined(BLUR_HORIZONTAL)
    return blur_line(p, ivec2(1, 0));
#elif defined(BLUR_VERTICAL)
    return blur_line(p, ivec2(0, 1));
#elif defined(BLUR_HYBRID)
    return blur_hybrid(p);
#elif defined(BLUR_GATHER)
    float sigma;
    int R;
    pixel_sigma(p, sigma, R);
    return sigma <= 0.0 ? texelFetch(u_src, p, 0).r : gather_gauss(u_src, p, textureSize(u_depth, 0), sigma, R);
#elif defined(BLUR_COLUMNS)
    return blur_columns(p);
#elif defined(BLUR_DISK)
    return blur_disk(p);
#else
#error "blur.glsl: define BLUR_HORIZONTAL, BLUR_VERTICAL, BLUR_HYBRID, BLUR_GATHER, BLUR_ROWS, BLUR_COLUMNS or BLUR_DISK"
#endif
}
#endif
