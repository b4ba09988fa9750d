// noise.frag as a compute pass (the pixel stage "compute"; pixelpass.glsl).
#define COMPUTE_PIXELS
#include "noise.frag"
