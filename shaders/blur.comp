// Depth-of-field blur (blur.glsl) as a compute pass; BLUR_ROWS writes its moments (u_out) and
// row records (u_out_b), the other passes the grey.
#include "comp_pass.glsl"
#include "blur.glsl"
#ifdef BLUR_ROWS
layout(rgba32f, binding = IMAGE_PASS_OUT) uniform writeonly image2D u_out;
layout(rgba32f, binding = IMAGE_PASS_OUT_B) uniform writeonly image2D u_out_b;
#else
layout(r32f, binding = IMAGE_PASS_OUT) uniform writeonly image2D u_out;
#endif

void main() {
    if (PASS_OUTSIDE) return;
#ifdef BLUR_ROWS
    vec4 moments, rows;
    blur_rows(PASS_PIXEL, moments, rows);
    imageStore(u_out, PASS_PIXEL, moments);
    imageStore(u_out_b, PASS_PIXEL, rows);
#else
    imageStore(u_out, PASS_PIXEL, vec4(blur(PASS_PIXEL)));
#endif
}
