// One sample's values in the deformation target (frag_targets.glsl or comp_targets.glsl,
// included before): its grey, depth Z and, with TRUTH, the truth maps — the reference point,
// (xi, eta) and the element; FP64 builds write the float64 values as float32 hi + lo, split
// with bit operations (hilo.glsl); float32 ones the reference point's rounding residual `lo`
// (REF_LOCAL's dropped part, else 0).
#include "hilo.glsl"

void write_sample(float grey, int elem, real xi, real eta, real2 ref, real Z, real2 lo) {
    out_grey = grey;
#ifdef DEPTH_OUT
    out_depth = float(Z);
#endif
#ifdef TRUTH
#if defined(FP64)
    vec4 ref_hl = split_double2(ref), xe_hl = split_double2(real2(xi, eta));
    out_map = vec4(ref_hl.xy, xe_hl.xy);
    out_extra = vec4(float(elem + 1), ref_hl.zw, 0.0);
#ifdef TRUTH_LO
    out_lo = xe_hl.zw;
#endif
#else
    out_map = vec4(vec2(ref), float(xi), float(eta));
    out_extra = vec4(float(elem + 1), vec2(lo), 0.0);
#endif
#endif
}
