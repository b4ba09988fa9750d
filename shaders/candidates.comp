// Pass 1 of the exact and q4 modes: per element (one invocation each) over the pixels of its
// cover's box, list the element at every pixel where its tight rectangle meets the pixel's
// samples (the square of half-width u_half around its centre). An element whose box is too
// large sets LIST_BIG and is listed by its cover triangles instead (exact.vert BIG_ONLY +
// candidates.frag). A pixel with more than CANDIDATES entries is left to the fallback.
#include "list_writer.glsl"
#include "cover.glsl"

layout(local_size_x = 64) in;

uniform int u_count;     // elements
uniform ivec2 u_size;    // image W, H (px)
uniform float u_half;    // 0.5 - 0.5 / SS: the pixel's samples lie within this of its centre

void main() {
    int e = int((gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * gl_WorkGroupSize.x
                + gl_LocalInvocationID.x);
    if (e >= u_count) return;
    ivec2 a, b;
    if (!cover_box(e, u_size, a, b)) {
        LIST_BIG = 1u;
        return;
    }
    for (int y = a.y; y <= b.y; ++y)
        for (int x = a.x; x <= b.x; ++x)
            if (in_tight(e, vec2(x, y), u_half)) list_candidate(ivec2(x, y), e);
}
