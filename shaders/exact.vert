// Mode exact: a conservative rectangle per element (computed in float64 on the CPU); the
// fragment stage decides coverage by intersecting each pixel's ray with the element.
in vec2 in_px;       // corner of the element's cover rectangle (px, geometry.py)
in int in_elem;

uniform vec2 u_size;

flat out int v_elem;

void main() {
    gl_Position = vec4((in_px + 0.5) / u_size * 2.0 - 1.0, 0.0, 1.0);
    v_elem = in_elem;
}
