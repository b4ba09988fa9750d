// Pass 1 of the exact and q4 modes for the elements candidates.comp leaves out (their cover's
// box is too large for one invocation): at pixel resolution over their cover rectangles
// (exact.vert BIG_ONLY), each fragment lists its element where the element's tight rectangle
// meets the pixel's samples (the square of half-width u_half around its centre).
#include "list_writer.glsl"

flat in int v_elem;
uniform float u_half;   // 0.5 - 0.5 / SS: the pixel's samples lie within this of its centre

void main() {
    if (!in_tight(v_elem, gl_FragCoord.xy - 0.5, u_half)) discard;
    list_candidate(ivec2(gl_FragCoord.xy), v_elem);
}
