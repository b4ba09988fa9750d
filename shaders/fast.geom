// Mode fast: each triangle of deform.vert passed on with its three vertices as flat data, so
// that deform.frag interpolates at the sample's exact pixel point from the vertices as
// projected (float32), as the oracle does (glsim.backends.cpu._fast), instead of using the
// rasterizer's attribute interpolation (NVIDIA interpolates over the vertices snapped to its
// sub-pixel grid, up to 1/512 px away, with unspecified precision; design notes "GPU facts").
// FAST_VISIBILITY (the compute pixel stage): each triangle's record also kept (fasttriangles.glsl)
// and its index passed on (g_tri), which is all deform.frag then writes.
#include "fasttriangles.glsl"
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;

in vec2 v_uv[];      // projected vertex (px)
in vec2 v_ref[];
in vec2 v_xe[];
in float v_depth[];
flat in int v_elem[];

flat out vec2 g_uv[3];
flat out vec2 g_ref[3];
flat out vec2 g_xe[3];
flat out float g_z[3];
flat out int g_elem;
flat out int g_tri;

void main() {
#ifdef FAST_VISIBILITY
    int b = FAST_RECORD * gl_PrimitiveIDIn;
    for (int i = 0; i < 3; ++i) {
        fast_rec[b + 2 * i] = v_uv[i].x;
        fast_rec[b + 2 * i + 1] = v_uv[i].y;
        fast_rec[b + 6 + 2 * i] = v_ref[i].x;
        fast_rec[b + 7 + 2 * i] = v_ref[i].y;
        fast_rec[b + 12 + 2 * i] = v_xe[i].x;
        fast_rec[b + 13 + 2 * i] = v_xe[i].y;
        fast_rec[b + 18 + i] = v_depth[i];
    }
    fast_rec[b + 21] = intBitsToFloat(v_elem[0]);
#endif
    for (int k = 0; k < 3; ++k) {
        for (int i = 0; i < 3; ++i) {   // flat outputs are the last emitted vertex's: set per vertex
            g_uv[i] = v_uv[i];
            g_ref[i] = v_ref[i];
            g_xe[i] = v_xe[i];
            g_z[i] = v_depth[i];
        }
        g_elem = v_elem[0];
        g_tri = gl_PrimitiveIDIn;
        gl_Position = gl_in[k].gl_Position;
        EmitVertex();
    }
    EndPrimitive();
}
