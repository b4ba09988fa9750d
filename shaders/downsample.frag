// The box filter (box.glsl) as a fragment pass.
#include "frag_grey.glsl"
#include "box.glsl"

void main() {
    float value;
    if (!box_filter(PASS_PIXEL, value)) PASS_SKIP;
    PASS_WRITE(value);
}
