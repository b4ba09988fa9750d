// Pass 1 of the exact and q4 modes, at pixel resolution over the cover rectangles (exact.vert):
// each fragment lists its element at the pixel where the element's tight rectangle meets the
// pixel's samples (the square of half-width u_half around its centre). A pixel with more than
// CANDIDATES entries is left to the fallback.
#include "candidates.glsl"

flat in int v_elem;
// which passes pass 2 needs (reset by the backend): a pixel with more than one candidate, one
// with more than CANDIDATES
layout(std430, binding = 13) buffer ListFlags { uint multiple; uint overflowed; };
uniform float u_half;   // 0.5 - 0.5 / SS: the pixel's samples lie within this of its centre

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    if (!in_tight(v_elem, gl_FragCoord.xy - 0.5, u_half)) discard;
    uint n = imageAtomicAdd(u_cand_count, pix, 1u);
    if (n < uint(CANDIDATES)) imageStore(u_cand_list, ivec3(pix, int(n)), uvec4(uint(v_elem)));
    else overflowed = 1u;
    if (n == 1u) multiple = 1u;
}
