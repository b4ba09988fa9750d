// Vignetting (vignette.glsl) as a fragment pass.
#include "frag_grey.glsl"
#include "vignette.glsl"

void main() {
    PASS_WRITE(vignette(PASS_PIXEL));
}
