// Pass 2 of mode fast (deform.vert, fast.geom; depth test): each sample of a triangle
// interpolated at its exact pixel point (fast_sample.glsl) and shaded; a sample whose
// reference point lies outside the reference image is dropped and counted.
#include "fast_sample.glsl"
#include "reference.glsl"
#include "shading.glsl"
#include "frag_targets.glsl"
#include "write_sample.glsl"

flat in vec2 g_uv[3];
flat in vec2 g_ref[3];
flat in vec2 g_xe[3];
flat in float g_z[3];
flat in int g_elem;

void main() {
    real2 ref;
    real xi, eta;
    float Z;
    fast_sample(ivec2(gl_FragCoord.xy), g_uv, g_ref, g_xe, g_z, ref, xi, eta, Z);
    if (!inside_reference(ref)) {
        atomicAdd(dropped_samples, 1u);  // counted for the warning (glsim.stages.view.warn_dropped)
        discard;
    }
    write_sample(shade_sample(g_elem, xi, eta, ref), g_elem, xi, eta, ref, Z, real2(0.0));
}
