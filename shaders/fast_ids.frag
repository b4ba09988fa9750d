// Pass 2 of mode fast in the compute pixel stage, first half (deform.vert, fast_records.geom;
// the same depth test and drops as fast.frag): each sample's triangle + 1, whose record
// fast_shade.comp shades.
#include "fast_sample.glsl"
#include "reference.glsl"

flat in vec2 g_uv[3];
flat in vec2 g_ref[3];
flat in vec2 g_xe[3];
flat in float g_z[3];
flat in int g_tri;

layout(location = 0) out uint out_triangle;

void main() {
    real2 ref;
    real xi, eta;
    float Z;
    fast_sample(ivec2(gl_FragCoord.xy), g_uv, g_ref, g_xe, g_z, ref, xi, eta, Z);
    if (!inside_reference(ref)) {
        atomicAdd(dropped_samples, 1u);  // counted for the warning (glsim.stages.view.warn_dropped)
        discard;
    }
    out_triangle = uint(g_tri + 1);
}
