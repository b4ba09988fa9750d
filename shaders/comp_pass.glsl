// A full-screen pass as a compute pass (glsim.backends.gl.plan's pixel stage "compute"): 16×8
// work groups over the pass's output image u_out (unit IMAGE_PASS_OUT), whose invocations
// beyond it end at once (PASS_OUTSIDE, main's first test). PASS_PIXEL is the pixel this
// invocation writes, PASS_SKIP leaves it as it is.
layout(local_size_x = 16, local_size_y = 8) in;
#define PASS_PIXEL ivec2(gl_GlobalInvocationID.xy)
#define PASS_SKIP return
#define PASS_OUTSIDE any(greaterThanEqual(PASS_PIXEL, imageSize(u_out)))
