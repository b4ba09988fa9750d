// Mode fast's geometry stage (fast.geom, fast_records.geom): each triangle of deform.vert passed
// on with its three vertices as flat data, so that the fragment stage interpolates at the
// sample's exact pixel point from the vertices as projected (float32), as the oracle does
// (glsim.backends.cpu._fast), instead of using the rasterizer's attribute interpolation (NVIDIA
// interpolates over the vertices snapped to its sub-pixel grid, up to 1/512 px away, with
// unspecified precision; design notes "GPU facts").
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

void emit_triangle() {
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
