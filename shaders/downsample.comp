// The box filter as a compute pass (the pixel stage "compute"); downsample.frag holds the code.
#define COMPUTE_PIXELS
#include "downsample.frag"
