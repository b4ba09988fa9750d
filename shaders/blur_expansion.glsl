// The expansion scheme of blur.glsl (glsim.effects.dof row_moments, blur_expansion): BLUR_ROWS,
// each row's moments in its own sigma, then BLUR_COLUMNS, expanded to the output pixel's sigma
// and window. Part of blur.glsl, which includes it (pixel_sigma, the textures).
const float EXP_CHORD = 3.194528;  // (e^2 - 1) / 2: exp(x) <= 1 + EXP_CHORD x on [0, 2]

// BLUR_ROWS: the moments and the row record (blur_columns reads both)
void blur_rows(ivec2 p, out vec4 moments, out vec4 rows) {
    ivec2 size = textureSize(u_depth, 0);
    float sigma;
    int R;
    pixel_sigma(p, sigma, R);
    // M_n = sum_k w_k k^(2n) (I(p + k) - I(p)), n = 0..3, w_k = exp(c k^2) of this pixel's own
    // sigma and window; out_rows = (max_k |I(p + k) - I(p)| * sum_k w_k k^8 (the remainder's
    // factor), c, R (-1: no sigma, the row is summed directly), I(p)). The weights come from
    // the recurrence w_(k+1) = w_k a_k, a_(k+1) = a_k exp(2c) (k ulps; exp is dear on llvmpipe).
    float I0 = texelFetch(u_src, p, 0).r;
    if (sigma <= 0.0) {
        moments = vec4(0.0);
        rows = vec4(0.0, 0.0, -1.0, I0);
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
    moments = M;
    rows = vec4(F * N4, c, float(R), I0);
}

// BLUR_COLUMNS
float blur_columns(ivec2 p) {
    ivec2 size = textureSize(u_depth, 0);
    float sigma;
    int R;
    pixel_sigma(p, sigma, R);
    if (sigma <= 0.0) {
        return texelFetch(u_image, p, 0).r;
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
    return acc / (Bv * Bp);
}
