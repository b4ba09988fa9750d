// A full-screen pass as a fragment pass (fullscreen.vert; glsim.backends.gl.plan's pixel stage
// "fragment"): PASS_PIXEL is the pixel this invocation writes, PASS_SKIP leaves it as it is.
#define PASS_PIXEL ivec2(gl_FragCoord.xy)
#define PASS_SKIP discard
