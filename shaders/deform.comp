// Pass 2 of the exact and q4 modes as a compute pass (the pixel stage "compute",
// glsim.backends.gl.plan): the samples of pixels with one candidate; deform.frag holds the code.
#define COMPUTE_PIXELS
#include "deform.frag"
