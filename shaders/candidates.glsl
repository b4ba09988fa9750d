// Candidate lists of the exact and q4 modes: per pixel, how many elements' covers may hold one
// of its samples (u_cand_count) and the first CANDIDATES of them (u_cand_list, one layer each).
// Written by pass 1 (list_writer.glsl), read by pass 2 (list_reader.glsl); the backend clears
// the counts before each view.
#define CANDIDATES 8
// a count set by subsamples.frag: the pixel is done (every later pass skips it)
#define LIST_DONE 0xFFFFFFFFu
layout(r32ui, binding = IMAGE_CAND_COUNT) uniform coherent uimage2D u_cand_count;
layout(r32ui, binding = IMAGE_CAND_LIST) uniform coherent uimage2DArray u_cand_list;
// per element, from view.comp: its tight rectangle, padded only for float32 rounding
// (glsim.stages.view.TIGHT_PAD_PX): (a.x, a.y, lo_a, hi_a), (lo_b, hi_b, 0, 0) along the unit
// axes a and b = (-a.y, a.x), px
layout(std430, binding = BINDING_TIGHT) readonly buffer Tight { vec4 tight[]; };

// Whether element e's tight rectangle meets the square of half-width `grow` around p (px).
bool in_tight(int e, vec2 p, float grow) {
    vec4 t0 = tight[2 * e], t1 = tight[2 * e + 1];
    float g = grow * (abs(t0.x) + abs(t0.y));
    float pa = t0.x * p.x + t0.y * p.y;
    float pb = t0.x * p.y - t0.y * p.x;
    return pa >= t0.z - g && pa <= t0.w + g && pb >= t1.x - g && pb <= t1.y + g;
}
