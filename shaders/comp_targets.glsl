// The deformation target's textures as images in a compute pass (their units:
// glsim.backends.gl.bindings.IMAGES): write_sample.glsl sets the values, store_targets writes
// them to the sample's texel. A sample the pass leaves is left as cleared, as a fragment pass's
// discard leaves it.
layout(r32f, binding = IMAGE_GREY) uniform writeonly image2D u_out_grey;
float out_grey;
#ifdef TRUTH
layout(rgba32f, binding = IMAGE_MAP) uniform writeonly image2D u_out_map;
layout(rgba32f, binding = IMAGE_EXTRA) uniform writeonly image2D u_out_extra;
vec4 out_map, out_extra;
#ifdef TRUTH_LO
layout(rg32f, binding = IMAGE_LO) uniform writeonly image2D u_out_lo;
vec2 out_lo;
#endif
#endif
#ifdef DEPTH_OUT
layout(r32f, binding = IMAGE_DEPTH) uniform writeonly image2D u_out_depth;
float out_depth;
#endif

void store_targets(ivec2 at) {
    imageStore(u_out_grey, at, vec4(out_grey));
#ifdef TRUTH
    imageStore(u_out_map, at, out_map);
    imageStore(u_out_extra, at, out_extra);
#ifdef TRUTH_LO
    imageStore(u_out_lo, at, vec4(out_lo, 0.0, 0.0));
#endif
#endif
#ifdef DEPTH_OUT
    imageStore(u_out_depth, at, vec4(out_depth));
#endif
}
