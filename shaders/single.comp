// Pass 2 of modes exact and q4 in the compute pixel stage: single.frag's samples, one
// invocation each, over classify.comp's list of pixels with one candidate (pixellists.glsl),
// dispatched indirectly; the values written to the target as images.
#include "pixellists.glsl"
#include "owners.glsl"
#include "shading.glsl"
#include "comp_targets.glsl"
#include "write_sample.glsl"

layout(local_size_x = LIST_LOCAL) in;

void main() {
    ivec2 at;
    if (!listed_sample(0u, at)) return;
    int elem = candidate(at / SS, 0);
    real xi, eta, Z;
    real2 ref;
    if (!map_single(at, elem, xi, eta, ref, Z)) return;
    write_sample(shade_sample(elem, xi, eta, ref), elem, xi, eta, ref, Z, ref_lo);
    store_targets(at);
}
