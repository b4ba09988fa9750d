// The deformation target's outputs in a fragment pass (write_sample.glsl sets them): grey, with
// TRUTH the truth maps, with DEPTH_OUT the camera-frame depth.
layout(location = 0) out float out_grey;
#ifdef TRUTH
layout(location = 1) out vec4 out_map;     // ref u, ref v, xi, eta (float32)
layout(location = 2) out vec4 out_extra;   // element + 1, ref u and v rounding residuals
#ifdef TRUTH_LO
layout(location = 3) out vec2 out_lo;      // xi, eta rounding residuals (FP64: float64 truth as hi + lo)
#endif
#endif
#ifdef DEPTH_OUT
layout(location = DEPTH_LOCATION) out float out_depth;  // camera-frame Z (mm)
#endif
