// Pass 2b of the exact and q4 modes (full screen, lists.vert): samples of pixels with 2 to
// CANDIDATES candidates test each and keep the nearest owner. deform.frag holds the code; its
// single-candidate pass stays straight-line (llvmpipe runs it much faster without the loop).
#define RESOLVE
#include "deform.frag"
