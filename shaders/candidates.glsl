// Candidate lists of the exact and q4 modes: per pixel, how many elements' covers may hold one
// of its samples (u_cand_count) and the first CANDIDATES of them (u_cand_list, one layer each).
// Written by candidates.comp (pass 1), read by deform.frag (pass 2); the backend clears the
// counts before each view.
#define CANDIDATES 8
// a count set by subsamples.frag: the pixel is done (every later pass skips it)
#define LIST_DONE 0xFFFFFFFFu
layout(r32ui, binding = IMAGE_CAND_COUNT) uniform coherent uimage2D u_cand_count;
layout(r32ui, binding = IMAGE_CAND_LIST) uniform coherent uimage2DArray u_cand_list;
// per element, from view.comp: its tight rectangle, padded only for float32 rounding
// (glsim.stages.view.TIGHT_PAD_PX): (a.x, a.y, lo_a, hi_a), (lo_b, hi_b, 0, 0) along the unit
// axes a and b = (-a.y, a.x), px
layout(std430, binding = BINDING_TIGHT) readonly buffer Tight { vec4 tight[]; };

#ifdef LIST_WRITER
// pass 1 (candidates.comp, candidates.frag): which draws the view needs, as the instance counts
// of three indirect draw commands of 20 bytes each (written by the backend before pass 1, so no
// draw waits for the host to read them): [0] candidates.frag over the covers of the elements
// whose box candidates.comp left to their triangles, [1] the fallback over the cover rectangles
// (a pixel with more than CANDIDATES), [2] resolve.frag's full-screen triangle (a pixel with
// more than one)
layout(std430, binding = BINDING_LIST_FLAGS) buffer ListFlags { uint draws[15]; };
#define LIST_BIG draws[1]
#define LIST_OVERFLOWED draws[6]
#define LIST_MULTIPLE draws[11]

// Add element e to pixel pix's list.
void list_candidate(ivec2 pix, int e) {
    uint n = imageAtomicAdd(u_cand_count, pix, 1u);
    if (n < uint(CANDIDATES)) imageStore(u_cand_list, ivec3(pix, int(n)), uvec4(uint(e)));
    else LIST_OVERFLOWED = 1u;
    if (n == 1u) LIST_MULTIPLE = 1u;
}
#endif

#ifdef CANDIDATE_TEXTURES
// pass 2 reads the lists as textures (their units: glsim.backends.gl.bindings.SAMPLERS)
layout(binding = SAMPLER_COUNT_TEX) uniform usampler2D u_count_tex;
layout(binding = SAMPLER_LIST_TEX) uniform usampler2DArray u_list_tex;
uint candidate_count(ivec2 pix) { return texelFetch(u_count_tex, pix, 0).x; }
int candidate(ivec2 pix, int k) { return int(texelFetch(u_list_tex, ivec3(pix, k), 0).x); }
#else
uint candidate_count(ivec2 pix) { return imageLoad(u_cand_count, pix).x; }
int candidate(ivec2 pix, int k) { return int(imageLoad(u_cand_list, ivec3(pix, k)).x); }
#endif

// Whether element e's tight rectangle meets the square of half-width `grow` around p (px).
bool in_tight(int e, vec2 p, float grow) {
    vec4 t0 = tight[2 * e], t1 = tight[2 * e + 1];
    float g = grow * (abs(t0.x) + abs(t0.y));
    float pa = t0.x * p.x + t0.y * p.y;
    float pb = t0.x * p.y - t0.y * p.x;
    return pa >= t0.z - g && pa <= t0.w + g && pb >= t1.x - g && pb <= t1.y + g;
}
