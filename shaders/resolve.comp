// Pass 2b of modes exact and q4 in the compute pixel stage: resolve.frag's samples, one
// invocation each, over classify.comp's list of pixels with 2 to CANDIDATES candidates
// (pixellists.glsl), dispatched indirectly; the values written to the target as images.
#include "pixellists.glsl"
#include "owners.glsl"
#include "shading.glsl"
#include "comp_targets.glsl"
#include "write_sample.glsl"

layout(local_size_x = LIST_LOCAL) in;

void main() {
    ivec2 at;
    if (!listed_sample(1u, at)) return;
    int elem;
    real xi, eta, Z;
    real2 ref;
    if (!map_nearest(at, elem, xi, eta, ref, Z)) return;
    write_sample(shade_sample(elem, xi, eta, ref), elem, xi, eta, ref, Z, ref_lo);
    store_targets(at);
}
