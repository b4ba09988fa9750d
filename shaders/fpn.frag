// Fixed-pattern noise (fpn.glsl) as a fragment pass.
#include "frag_grey.glsl"
#include "fpn.glsl"

void main() {
    PASS_WRITE(fixed_pattern(PASS_PIXEL));
}
