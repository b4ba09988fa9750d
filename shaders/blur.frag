// Depth-of-field blur (blur.glsl) as a fragment pass; BLUR_ROWS writes its moments and row
// records, the other passes the grey.
#include "frag_pass.glsl"
#include "blur.glsl"
#ifdef BLUR_ROWS
layout(location = 0) out vec4 out_moments;
layout(location = 1) out vec4 out_rows;
#else
out float out_grey;
#endif

void main() {
#ifdef BLUR_ROWS
    vec4 moments, rows;
    blur_rows(PASS_PIXEL, moments, rows);
    out_moments = moments;
    out_rows = rows;
#else
    out_grey = blur(PASS_PIXEL);
#endif
}
