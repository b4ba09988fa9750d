// Pixel integration: box filter over the SS x SS samples of each pixel. With COVERED_MEAN the
// mean is taken over non-zero samples only (depth maps: 0 = no surface). With SKIP_DONE the
// pixels subsamples.frag finished (candidate count LIST_DONE) are left as they are.
#ifdef SKIP_DONE
#include "candidates.glsl"
#endif
layout(binding = SAMPLER_SAMPLES) uniform sampler2D u_samples;

out float out_grey;

void main() {
#ifdef SKIP_DONE
    if (imageLoad(u_cand_count, ivec2(gl_FragCoord.xy)).x == LIST_DONE) discard;
#endif
    ivec2 base = ivec2(gl_FragCoord.xy) * SS;
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
    out_grey = n > 0.0 ? acc / n : 0.0;
#else
    out_grey = acc / float(SS * SS);
#endif
}
