// Pass 1b of the exact and q4 modes with the compute pixel stage (one invocation per pixel):
// lists the pixels by their candidate count into the layers of pixellists.glsl, as classify.frag
// sorts them into depth layers for the fragment stage: pixels with no candidate, an overflowed
// list (the fallback's) or a Newton-done one (LIST_DONE) are in neither. Each work group counts
// its own in shared memory and reserves its places with one atomic per layer; the order within
// a list is the GPU's, which no image depends on (each pixel writes only its own samples).
#include "candidates.glsl"
#include "pixellists.glsl"

layout(local_size_x = 16, local_size_y = 8) in;

shared uint s_count[2], s_base[2];

void main() {
    ivec2 pix = ivec2(gl_GlobalInvocationID.xy);
    uint layer = 2u;   // none
    if (all(lessThan(pix, imageSize(u_cand_count)))) {
        uint n = imageLoad(u_cand_count, pix).x;
        layer = n == 1u ? 0u : n >= 2u && n <= uint(CANDIDATES) ? 1u : 2u;
    }
    // (memoryBarrierShared before each barrier, as is common practice, so that the shared
    // counts written before it are seen after it; both in uniform control flow)
    if (gl_LocalInvocationIndex < 2u) s_count[gl_LocalInvocationIndex] = 0u;
    memoryBarrierShared();
    barrier();
    uint k = layer < 2u ? atomicAdd(s_count[layer], 1u) : 0u;
    memoryBarrierShared();
    barrier();
    if (gl_LocalInvocationIndex < 2u) {
        uint l = gl_LocalInvocationIndex, m = s_count[l];
        if (m > 0u) {
            uint base = atomicAdd(layer_count[l], m);
            s_base[l] = base;
            // the work groups its samples need so far (W·H·SS² < 2^32: the target is a texture)
            uint groups = ((base + m) * uint(SS * SS) + uint(LIST_LOCAL) - 1u) / uint(LIST_LOCAL);
            atomicMax(layer_args[3u * l], min(groups, LIST_MAX_GROUPS));
            atomicMax(layer_args[3u * l + 1u], (groups + LIST_MAX_GROUPS - 1u) / LIST_MAX_GROUPS);
        }
    }
    memoryBarrierShared();
    barrier();
    uint w = uint(pix.x) | (uint(pix.y) << 16);
    if (layer < 2u) pixels[LIST_SLOT(layer, s_base[layer] + k)] = w;
}
