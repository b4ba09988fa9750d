// Pass 1b of the exact and q4 modes, full screen at sample resolution (lists.vert): sorts the
// samples by their pixel's candidate count into depth layers, so that each pass 2 program runs
// (early depth test, depth func EQUAL) only where it has work: one candidate → LAYER_SINGLE,
// 2..CANDIDATES → LAYER_MULTIPLE; no candidate or an overflowed list keeps the cleared 1.0
// (the fallback's depth test starts from it). Llvmpipe shades masked-out lanes of a branch, so
// a discard at the top of a full-screen pass does not make its pixels cheap; a failed early
// depth test does.
#include "candidates.glsl"

void main() {
    uint n = imageLoad(u_cand_count, ivec2(gl_FragCoord.xy) / SS).x;
    if (n == 0u || n > uint(CANDIDATES)) discard;
    gl_FragDepth = n == 1u ? LAYER_SINGLE : LAYER_MULTIPLE;
}
