// Pass 2 of the exact and q4 modes: one triangle covering the viewport (as fullscreen.vert);
// single.frag and resolve.frag find each sample's elements in the candidate lists (v_elem
// unused). At window depth u_layer: the pass runs where classify.frag put that layer (depth
// func EQUAL).
flat out int v_elem;

uniform float u_layer;

void main() {
    vec2 p = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    gl_Position = vec4(p * 2.0 - 1.0, 2.0 * u_layer - 1.0, 1.0);
    v_elem = -1;
}
