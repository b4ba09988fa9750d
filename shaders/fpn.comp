// Fixed-pattern noise (fpn.glsl) as a compute pass.
#include "comp_grey.glsl"
#include "fpn.glsl"

void main() {
    if (PASS_OUTSIDE) return;
    PASS_WRITE(fixed_pattern(PASS_PIXEL));
}
