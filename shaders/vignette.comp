// Vignetting (vignette.glsl) as a compute pass.
#include "comp_grey.glsl"
#include "vignette.glsl"

void main() {
    if (PASS_OUTSIDE) return;
    PASS_WRITE(vignette(PASS_PIXEL));
}
