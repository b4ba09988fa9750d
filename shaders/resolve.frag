// Pass 2b of modes exact and q4, full screen at SS x SS samples per pixel (lists.vert): the
// samples of pixels with 2 to CANDIDATES candidates keep their nearest owner (owners.glsl).
// classify.frag put those samples in this pass's depth layer; the early depth test keeps the
// pass to them.
layout(early_fragment_tests) in;
#include "owners.glsl"
#include "shading.glsl"
#include "frag_targets.glsl"
#include "write_sample.glsl"

uniform float u_far;      // depth range (mm): gl_FragDepth = Z / u_far

void main() {
    ivec2 at = ivec2(gl_FragCoord.xy);
    int elem;
    real xi, eta, Z;
    real2 ref;
    if (!map_nearest(at, elem, xi, eta, ref, Z)) discard;
    gl_FragDepth = float(Z) / u_far;
    write_sample(shade_sample(elem, xi, eta, ref), elem, xi, eta, ref, Z, ref_lo);
}
