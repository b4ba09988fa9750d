// The box filter (box.glsl) as a compute pass.
#include "comp_grey.glsl"
#include "box.glsl"

void main() {
    if (PASS_OUTSIDE) return;
    float value;
    if (!box_filter(PASS_PIXEL, value)) PASS_SKIP;
    PASS_WRITE(value);
}
