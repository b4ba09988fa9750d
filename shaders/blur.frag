// Depth-of-field blur, one full-screen pass (the GLSL twin of glsim/effects/dof.py). One define
// chooses the pass; the scheme (optics.scheme) chooses the passes:
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
#ifndef BLUR_ROWS
#define GREY_PASS
#endif
#include "pixelpass.glsl"
#include "dof.glsl"

layout(binding = SAMPLER_SRC) uniform sampler2D u_src;      // R32F grey (BLUR_VERTICAL, BLUR_HYBRID: BLUR_HORIZONTAL's output)
layout(binding = SAMPLER_DEPTH) uniform sampler2D u_depth;    // R32F camera-frame depth Z (mm) per pixel, 0 = no surface
layout(binding = SAMPLER_IMAGE) uniform sampler2D u_image;    // BLUR_HYBRID, BLUR_COLUMNS: the unblurred grey
layout(binding = SAMPLER_MOMENTS) uniform sampler2D u_moments;  // BLUR_COLUMNS: BLUR_ROWS's moments M0..M3
layout(binding = SAMPLER_ROWS) uniform sampler2D u_rows;     // BLUR_COLUMNS: BLUR_ROWS's (remainder factor, c, R, grey) per pixel
uniform float u_expansion_tol;

#if defined(BLUR_ROWS) && defined(COMPUTE_PIXELS)
layout(rgba32f, binding = IMAGE_PASS_OUT) uniform writeonly image2D u_out;     // the moments
layout(rgba32f, binding = IMAGE_PASS_OUT_B) uniform writeonly image2D u_out_b; // the row records
#define ROWS_WRITE(m, r) imageStore(u_out, PASS_PIXEL, m); imageStore(u_out_b, PASS_PIXEL, r)
#elif defined(BLUR_ROWS)
layout(location = 0) out vec4 out_moments;
layout(location = 1) out vec4 out_rows;
#define ROWS_WRITE(m, r) out_moments = (m); out_rows = (r)
#endif

// ceil(3 sigma) as numpy's kernel_radius (in double in FP64 builds), cut to MAX_RADIUS
const float EXP_CHORD = 3.194528;  // (e^2 - 1) / 2: exp(x) <= 1 + EXP_CHORD x on [0, 2]

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

void main() {
    if (PASS_OUTSIDE) return;
    ivec2 p = PASS_PIXEL;
    ivec2 size = textureSize(u_depth, 0);
    real Z = real(texelFetch(u_depth, p, 0).r);
#ifndef BLUR_DISK
    real sigma_p = blur_sigma(Z);  // this pixel's sigma and window
    float sigma = float(sigma_p);
    int R = window(sigma_p);
#endif
#if defined(BLUR_HORIZONTAL) || defined(BLUR_VERTICAL)
    if (sigma <= 0.0) {
        PASS_WRITE(texelFetch(u_src, p, 0).r);
        return;
    }
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
        if (!inside(q, size)) continue;
        float w = exp(float(k * k) * c);
        acc += w * texelFetch(u_src, q, 0).r;
        wsum += w;
    }
    PASS_WRITE(acc / wsum);
#elif defined(BLUR_HYBRID)
    if (sigma <= 0.0) {
        PASS_WRITE(texelFetch(u_image, p, 0).r);
        return;
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
            PASS_WRITE(gather_gauss(u_image, p, size, sigma, R));
            return;
        }
        float w = exp(float(k * k) * c);
        acc += w * texelFetch(u_src, q, 0).r;
        wsum += w;
    }
    PASS_WRITE(acc / wsum);
#elif defined(BLUR_GATHER)
    PASS_WRITE(sigma <= 0.0 ? texelFetch(u_src, p, 0).r : gather_gauss(u_src, p, size, sigma, R));
#elif defined(BLUR_ROWS)
    // M_n = sum_k w_k k^(2n) (I(p + k) - I(p)), n = 0..3, w_k = exp(c k^2) of this pixel's own
    // sigma and window; out_rows = (max_k |I(p + k) - I(p)| * sum_k w_k k^8 (the remainder's
    // factor), c, R (-1: no sigma, the row is summed directly), I(p)). The weights come from
    // the recurrence w_(k+1) = w_k a_k, a_(k+1) = a_k exp(2c) (k ulps; exp is dear on llvmpipe).
    float I0 = texelFetch(u_src, p, 0).r;
    if (sigma <= 0.0) {
        ROWS_WRITE(vec4(0.0), vec4(0.0, 0.0, -1.0, I0));
        return;
    }
    float c = -0.5 / (sigma * sigma);
    float w = 1.0, a = exp(c), g2 = exp(2.0 * c);
    vec4 M = vec4(0.0);
    float N4 = 0.0, F = 0.0;
    for (int k = 1; k <= R; ++k) {  // k = 0 adds nothing: f = 0
        w *= a;
        a *= g2;
        bool right = p.x + k < size.x, left = p.x - k >= 0;
        float fr = right ? texelFetch(u_src, p + ivec2(k, 0), 0).r - I0 : 0.0;
        float fl = left ? texelFetch(u_src, p - ivec2(k, 0), 0).r - I0 : 0.0;
        float kk = float(k * k);
        M += (w * (fr + fl)) * vec4(1.0, kk, kk * kk, kk * kk * kk);
        N4 += w * (float(right) + float(left)) * ((kk * kk) * (kk * kk));
        F = max(F, max(abs(fr), abs(fl)));
    }
    ROWS_WRITE(M, vec4(F * N4, c, float(R), I0));
#elif defined(BLUR_COLUMNS)
    if (sigma <= 0.0) {
        PASS_WRITE(texelFetch(u_image, p, 0).r);
        return;
    }
    float c = -0.5 / (sigma * sigma);
    float g2 = exp(2.0 * c);
    float Bp = 1.0, Bv = 1.0;  // the row and column normalisers (clipped windows)
    {
        float w = 1.0, a = exp(c);
        for (int k = 1; k <= R; ++k) {
            w *= a;
            a *= g2;
            Bp += w * (float(p.x + k < size.x) + float(p.x - k >= 0));
            Bv += w * (float(p.y + k < size.y) + float(p.y - k >= 0));
        }
    }
    // A row's expansion is used if v * (its remainder bound) <= tol * Bp * Bv / (2R + 1): the
    // column's weighted sum then errs by at most tol of the rows' grey range. The bound's
    // exp(grow) is taken as 1 + grow (e^2 - 1) / 2 (its chord on [0, 2]); grow > 2: direct.
    float budget = 24.0 * u_expansion_tol * Bp * Bv / float(2 * R + 1);
    int y0 = max(p.y - R, 0), y1 = min(p.y + R, size.y - 1);
    float acc = 0.0;
    bool direct = false;  // some row to sum directly (a second loop, so that the rest skip it)
    int d0 = y0 - p.y;
    float v = exp(float(d0 * d0) * c), av = exp(float(2 * d0 + 1) * c);
    for (int y = y0; y <= y1; ++y) {
        ivec2 q = ivec2(p.x, y);
        vec4 rq = texelFetch(u_rows, q, 0);  // remainder factor, c_q, R_q (-1: none), I(q)
        int Rq = int(rq.z);
        float dc = c - rq.y;
        float grow = max(dc, 0.0) * float(Rq * Rq);
        float dc2 = dc * dc;
        if (Rq >= 0 && grow <= 2.0 && v * dc2 * dc2 * rq.x * (1.0 + EXP_CHORD * grow) <= budget) {
            float Iq = rq.w;
            vec4 M = texelFetch(u_moments, q, 0);
            float A = M.x + dc * (M.y + dc * (0.5 * M.z + dc * (M.w / 6.0)));
            // the taps between R_q and R: added (R > R_q) or taken away (R < R_q), exact weights
            int k0 = min(R, Rq) + 1;
            if (k0 <= max(R, Rq)) {
                float sgn = R > Rq ? 1.0 : -1.0;
                float w = sgn * exp(float(k0 * k0) * c), a = exp(float(2 * k0 + 1) * c);
                for (int k = k0; k <= max(R, Rq); ++k) {
                    if (q.x + k < size.x) A += w * (texelFetch(u_image, q + ivec2(k, 0), 0).r - Iq);
                    if (q.x - k >= 0) A += w * (texelFetch(u_image, q - ivec2(k, 0), 0).r - Iq);
                    w *= a;
                    a *= g2;
                }
            }
            acc += v * (Iq * Bp + A);
        } else {
            direct = true;
        }
        v *= av;
        av *= g2;
    }
    if (direct) {  // the same test again; the rows that failed it, summed directly
        int x0 = max(p.x - R, 0), x1 = min(p.x + R, size.x - 1);
        v = exp(float(d0 * d0) * c);
        av = exp(float(2 * d0 + 1) * c);
        for (int y = y0; y <= y1; ++y) {
            vec4 rq = texelFetch(u_rows, ivec2(p.x, y), 0);
            int Rq = int(rq.z);
            float dc = c - rq.y;
            float grow = max(dc, 0.0) * float(Rq * Rq);
            float dc2 = dc * dc;
            if (!(Rq >= 0 && grow <= 2.0 && v * dc2 * dc2 * rq.x * (1.0 + EXP_CHORD * grow) <= budget)) {
                float row = 0.0;
                for (int x = x0; x <= x1; ++x)
                    row += exp(float((x - p.x) * (x - p.x)) * c) * texelFetch(u_image, ivec2(x, y), 0).r;
                acc += v * row;
            }
            v *= av;
            av *= g2;
        }
    }
    PASS_WRITE(acc / (Bv * Bp));
#elif defined(BLUR_DISK)
    real r_p = blur_radius(Z);
    float r = float(r_p);
    if (r <= 0.0) {
        PASS_WRITE(texelFetch(u_src, p, 0).r);
        return;
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
    PASS_WRITE(acc / wsum);
#else
#error "blur.frag: define BLUR_HORIZONTAL, BLUR_VERTICAL, BLUR_HYBRID, BLUR_GATHER, BLUR_ROWS, BLUR_COLUMNS or BLUR_DISK"
#endif
}
