// Pixel integration: box filter over the SS x SS samples of each pixel. With COVERED_MEAN the
// mean is taken over non-zero samples only (depth maps: 0 = no surface). With SKIP_DONE the
// pixels subsamples.frag finished (candidate count LIST_DONE) are left as they are. Either
// pixel stage (pixelpass.glsl; downsample.comp).
#define GREY_PASS
#include "pixelpass.glsl"
#ifdef SKIP_DONE
#include "candidates.glsl"
#endif
layout(binding = SAMPLER_SAMPLES) uniform sampler2D u_samples;


void main() {
    if (PASS_OUTSIDE) return;
#ifdef SKIP_DONE
    if (imageLoad(u_cand_count, PASS_PIXEL).x == LIST_DONE) PASS_SKIP;
#endif
    ivec2 base = PASS_PIXEL * SS;
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
    PASS_WRITE(n > 0.0 ? acc / n : 0.0);
#else
    PASS_WRITE(acc / float(SS * SS));
#endif
}
