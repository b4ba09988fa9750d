// Each element's conservative cover rectangle (view.comp: 4 corners, px, pixel centres at
// integers) and the box of pixel centres it may hold. candidates.comp lists the elements whose
// box is at most BIN_MAX_SIDE pixels on each side, one invocation each: llvmpipe ends a shader
// after 65535 loop iterations of a SIMD vector, and a vector's nested loops over 8 such boxes
// take at most BIN_MAX_SIDE × (BIN_MAX_SIDE + 1). Larger boxes are left to the cover triangles
// (exact.vert BIG_ONLY + candidates.frag).
#define BIN_MAX_SIDE 192
layout(std430, binding = BINDING_COVER) readonly buffer Cover { vec2 cover[]; };

// The pixels [a, b] (inclusive) of element e's cover within an image of `size` (empty: b < a);
// false where the box is larger than BIN_MAX_SIDE on a side.
bool cover_box(int e, ivec2 size, out ivec2 a, out ivec2 b) {
    vec2 lo = min(min(cover[4 * e], cover[4 * e + 1]), min(cover[4 * e + 2], cover[4 * e + 3]));
    vec2 hi = max(max(cover[4 * e], cover[4 * e + 1]), max(cover[4 * e + 2], cover[4 * e + 3]));
    if (any(isnan(lo)) || any(isnan(hi))) {   // empty (the rasterizer drops such covers too)
        a = ivec2(0);
        b = ivec2(-1);
        return true;
    }
    a = ivec2(clamp(ceil(lo), vec2(0.0), vec2(size)));
    b = ivec2(clamp(floor(hi), vec2(-1.0), vec2(size - 1)));
    return all(lessThanEqual(b - a + 1, ivec2(BIN_MAX_SIDE)));
}
