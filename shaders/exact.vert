// Modes exact and q4: each element's conservative cover rectangle, written per view by
// view.comp; the fragment stage decides coverage (the shared tie rule). No vertex attributes:
// vertex 4 e + i is corner i of element e's rectangle (index buffer: two triangles each).
// BIG_ONLY (pass 1 after candidates.comp): only the elements whose box that pass left out.
#include "cover.glsl"

uniform vec2 u_size;

flat out int v_elem;

void main() {
    v_elem = gl_VertexID >> 2;
    vec2 px = cover[gl_VertexID];
    gl_Position = vec4((px + 0.5) / u_size * 2.0 - 1.0, 0.0, 1.0);
#ifdef BIG_ONLY
    ivec2 a, b;
    if (cover_box(v_elem, ivec2(u_size), a, b)) gl_Position = vec4(2.0, 2.0, 2.0, 1.0);  // outside: culled
#endif
}
