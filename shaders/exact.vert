// Modes exact and q4: each element's conservative cover rectangle, written per view by
// view.comp; the fragment stage decides coverage (the shared tie rule). No vertex attributes:
// vertex 4 e + i is corner i of element e's rectangle (index buffer: two triangles each).
layout(std430, binding = 9) readonly buffer Cover { vec2 cover[]; };

uniform vec2 u_size;

flat out int v_elem;

void main() {
    vec2 px = cover[gl_VertexID];
    gl_Position = vec4((px + 0.5) / u_size * 2.0 - 1.0, 0.0, 1.0);
    v_elem = gl_VertexID >> 2;
}
