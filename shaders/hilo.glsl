// float64 → float32 (hi, lo) split made with bit operations (FP64 builds): `x - double(float(x))`
// may be folded to 0 by a compiler that treats the round trip as the identity (design notes,
// "GPU facts"); clearing bits cannot be folded. hi is x with its low 29 mantissa bits cleared
// (exact in float32 for |x| in float32's normal range), lo = x - hi (exact in float64) rounded
// to float32: hi + lo = x within 2^-48 |x|.
#ifdef FP64
vec2 split_double(double x) {
    uvec2 w = unpackDouble2x32(x);   // (low word, high word)
    precise double hi = packDouble2x32(uvec2(w.x & 0xE0000000u, w.y));
    precise double lo = x - hi;
    return vec2(float(hi), float(lo));
}

// (hi.x, hi.y, lo.x, lo.y) of a dvec2
vec4 split_double2(dvec2 x) {
    vec2 a = split_double(x.x), b = split_double(x.y);
    return vec4(a.x, b.x, a.y, b.y);
}
#endif
