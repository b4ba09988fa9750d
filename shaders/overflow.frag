// Pass 2c of modes exact and q4 (exact.vert over the cover rectangles, depth test): the samples
// of pixels whose candidate list overflowed, one element per fragment, as every pixel was drawn
// before the lists; the nearest owner wins the depth test.
#include "owners.glsl"
#include "shading.glsl"
#include "frag_targets.glsl"
#include "write_sample.glsl"

uniform float u_far;      // depth range (mm): gl_FragDepth = Z / u_far
flat in int v_elem;

void main() {
    ivec2 at = ivec2(gl_FragCoord.xy);
    uint n = candidate_count(at / SS);
    if (n <= uint(CANDIDATES) || n == LIST_DONE) discard;
    real xi, eta, Z;
    real2 ref;
    if (!map_single(at, v_elem, xi, eta, ref, Z)) discard;
    gl_FragDepth = float(Z) / u_far;
    write_sample(shade_sample(v_elem, xi, eta, ref), v_elem, xi, eta, ref, Z, ref_lo);
}
