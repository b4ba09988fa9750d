// The lens PSF (psf.glsl) as a fragment pass.
#include "frag_grey.glsl"
#include "psf.glsl"

void main() {
    PASS_WRITE(psf(PASS_PIXEL));
}
