// Pass 2b of the exact and q4 modes as a compute pass (the pixel stage "compute"): the samples
// of pixels with 2 to CANDIDATES candidates; deform.frag holds the code.
#define RESOLVE
#define COMPUTE_PIXELS
#include "deform.frag"
