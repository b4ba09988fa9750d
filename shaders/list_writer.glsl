// Pass 1 (candidates.comp, candidates.frag) writing the candidate lists (candidates.glsl), and
// which draws the view needs, as the instance counts of three indirect draw commands of 20
// bytes each (written by the backend before pass 1, so no draw waits for the host to read
// them): [0] candidates.frag over the covers of the elements whose box candidates.comp left to
// their triangles, [1] the overflow pass over the cover rectangles (a pixel with more than
// CANDIDATES), [2] resolve.frag's full-screen triangle (a pixel with more than one)
#include "candidates.glsl"
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
