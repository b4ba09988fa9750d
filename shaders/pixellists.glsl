// The compute pixel stage's lists (glsim.backends.gl.plan; classify.comp writes them, single.comp
// and resolve.comp read them): per layer — 0: pixels with one candidate, 1: with 2..CANDIDATES —
// its indirect dispatch (groups along x and y, 1; the backend writes (0, 1, 1) before
// classify.comp), for one invocation per sample of its pixels, and its length; then the pixels as
// x | y << 16, layer 0 from the front of `pixels`, layer 1 from its back (W·H entries: a pixel is
// in one layer at most).
#include "candidates.glsl"
#define LIST_LOCAL 64            // single.comp's and resolve.comp's local size
#define LIST_MAX_GROUPS 65535u   // along x: GL's least GL_MAX_COMPUTE_WORK_GROUP_COUNT; then rows of them
layout(std430, binding = BINDING_PIXEL_LISTS) buffer PixelLists {
    uint layer_args[6];
    uint layer_count[2];
    uint pixels[];
};
// The place of a layer's j-th pixel in `pixels`, whose W·H entries end where the candidate counts'
// image (u_cand_count, W × H: candidates.glsl, declared before the macro is used) says, not where
// pixels.length() does: zink (Mesa 22.3, on lavapipe) gave the float32 exact resolve.comp a wrong
// length, so that its samples read other entries (glsim check's pixel-stage row found it); code
// that needs no .length() depends on no driver's.
#define LIST_END uint(imageSize(u_cand_count).x * imageSize(u_cand_count).y)
#define LIST_SLOT(layer, j) ((layer) == 0u ? (j) : LIST_END - 1u - (j))

// The sample of this invocation of a pass over `layer`'s list (one invocation per sample of a
// listed pixel: a loop over them ran far slower on llvmpipe); false beyond the list's end.
bool listed_sample(uint layer, out ivec2 at) {
    uint i = gl_GlobalInvocationID.y * gl_NumWorkGroups.x * uint(LIST_LOCAL) + gl_GlobalInvocationID.x;
    uint j = i / uint(SS * SS), k = i % uint(SS * SS);
    if (j >= layer_count[layer]) return false;
    uint w = pixels[LIST_SLOT(layer, j)];
    at = ivec2(w & 0xFFFFu, w >> 16) * SS + ivec2(k % uint(SS), k / uint(SS));
    return true;
}
