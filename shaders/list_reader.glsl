// Pass 2 reading the candidate lists (candidates.glsl) as textures (their units:
// glsim.backends.gl.bindings.SAMPLERS).
#include "candidates.glsl"
layout(binding = SAMPLER_COUNT_TEX) uniform usampler2D u_count_tex;
layout(binding = SAMPLER_LIST_TEX) uniform usampler2DArray u_list_tex;
uint candidate_count(ivec2 pix) { return texelFetch(u_count_tex, pix, 0).x; }
int candidate(ivec2 pix, int k) { return int(texelFetch(u_list_tex, ivec3(pix, k), 0).x); }
