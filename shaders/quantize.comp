// Quantisation as a compute pass (the pixel stage "compute"); quantize.frag holds the code.
#define COMPUTE_PIXELS
#include "quantize.frag"
