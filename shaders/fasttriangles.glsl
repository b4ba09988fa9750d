// Mode fast's triangle records in the compute pixel stage (glsim.backends.gl.plan):
// fast_records.geom keeps each triangle's (draw order, two per element) and fast_shade.comp
// reads the one a sample shows: its projected vertices (px), reference points, (xi, eta) and
// depths, and its element (bits), FAST_RECORD floats each.
#define FAST_RECORD 24
layout(std430, binding = BINDING_FAST_TRIANGLES) buffer FastTriangles { float fast_rec[]; };

void fast_triangle(int t, out vec2 uv[3], out vec2 ref[3], out vec2 xe[3], out float z[3], out int elem) {
    int b = FAST_RECORD * t;
    for (int i = 0; i < 3; ++i) {
        uv[i] = vec2(fast_rec[b + 2 * i], fast_rec[b + 2 * i + 1]);
        ref[i] = vec2(fast_rec[b + 6 + 2 * i], fast_rec[b + 7 + 2 * i]);
        xe[i] = vec2(fast_rec[b + 12 + 2 * i], fast_rec[b + 13 + 2 * i]);
        z[i] = fast_rec[b + 18 + i];
    }
    elem = floatBitsToInt(fast_rec[b + 21]);
}
