// The lens PSF (psf.glsl) as a compute pass.
#include "comp_grey.glsl"
#include "psf.glsl"

void main() {
    if (PASS_OUTSIDE) return;
    PASS_WRITE(psf(PASS_PIXEL));
}
