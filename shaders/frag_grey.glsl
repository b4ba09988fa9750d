// A fragment pass (frag_pass.glsl) that writes one float per pixel: PASS_WRITE(value).
#include "frag_pass.glsl"
out float out_grey;
#define PASS_WRITE(v) out_grey = (v)
