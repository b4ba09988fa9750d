// A full-screen pass in either pixel stage (glsim.backends.gl.plan): PASS_PIXEL is the pixel
// this invocation writes, PASS_SKIP leaves it as it is. COMPUTE_PIXELS: a compute pass, 16×8
// work groups over the output image u_out (unit IMAGE_PASS_OUT; an integer one's format
// OUT_FORMAT), whose invocations beyond it
// end at once (PASS_OUTSIDE, main's first test); else a fragment pass (fullscreen.vert).
// GREY_PASS: the pass writes one float per pixel, PASS_WRITE(value) (an R32F image or output);
// others declare their own u_out (compute) and outputs (fragment).
#ifdef COMPUTE_PIXELS
layout(local_size_x = 16, local_size_y = 8) in;
#define PASS_PIXEL ivec2(gl_GlobalInvocationID.xy)
#define PASS_SKIP return
#define PASS_OUTSIDE any(greaterThanEqual(PASS_PIXEL, imageSize(u_out)))
#else
#define PASS_PIXEL ivec2(gl_FragCoord.xy)
#define PASS_SKIP discard
#define PASS_OUTSIDE false
#endif
#ifdef GREY_PASS
#ifdef COMPUTE_PIXELS
layout(r32f, binding = IMAGE_PASS_OUT) uniform writeonly image2D u_out;
#define PASS_WRITE(v) imageStore(u_out, PASS_PIXEL, vec4(v))
#else
out float out_grey;
#define PASS_WRITE(v) out_grey = (v)
#endif
#endif
