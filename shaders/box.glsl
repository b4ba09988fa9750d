// Pixel integration: box filter over the SS x SS samples of each pixel (downsample.frag,
// downsample.comp). With COVERED_MEAN the mean is taken over non-zero samples only (depth maps:
// 0 = no surface). With SKIP_DONE the pixels subsamples.frag finished (candidate count
// LIST_DONE) are left as they are.
#ifdef SKIP_DONE
#include "candidates.glsl"
#endif
layout(binding = SAMPLER_SAMPLES) uniform sampler2D u_samples;

// The box-filtered value of pixel p; false where it is left as it is (SKIP_DONE).
bool box_filter(ivec2 p, out float value) {
#ifdef SKIP_DONE
    if (imageLoad(u_cand_count, p).x == LIST_DONE) return false;
#endif
    ivec2 base = p * SS;
    float acc = 0.0;
    float n = 0.0;
    for (int j = 0; j < SS; ++j)
        for (int i = 0; i < SS; ++i) {
            float v = texelFetch(u_samples, base + ivec2(i, j), 0).r;
            acc += v;
#ifdef COVERED_MEAN
            n += v > 0.0 ? 1.0 : 0.0;
#endif
        }
#ifdef COVERED_MEAN
    value = n > 0.0 ? acc / n : 0.0;
#else
    value = acc / float(SS * SS);
#endif
    return true;
}
