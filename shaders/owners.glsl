// Pass 2 of modes exact and q4, one sample: the element that owns it among its pixel's
// candidates (sample_map.glsl maps it into each). A sample is named by its texel `at` in the
// target of SS x SS samples per pixel (gl_FragCoord there is at + 0.5).
#include "sample_map.glsl"

// The sample's pixel point px (and px in float32, for the tight rectangles) and, in mode
// exact, its ray xn from the ray map; false where it has no ray.
bool locate_sample(ivec2 at, out real2 px, out vec2 sample_px, out real2 xn) {
#ifdef APERTURE
    px = aperture_sample(at);   // sensor.fill_factor < 1
    sample_px = vec2(px);
#else
    sample_px = (vec2(at) + 0.5) / float(SS) - 0.5;  // this sample's pixel coordinates
    px = real2(vec2(at) + 0.5) / real(SS) - 0.5;
#endif
    xn = real2(0.0);
#if defined(MODE_EXACT)
    if (!ray_at(u_rays, at, xn)) return false;
#endif
    return true;
}

// The sample mapped into element e, its one candidate (or the overflow pass's element): false
// where it has no ray, e does not own it (the tie rule) or it maps outside the reference
// (counted for the warning: glsim.stages.view.warn_dropped).
bool map_single(ivec2 at, int e, out real xi, out real eta, out real2 ref, out real Z) {
    real2 px, xn;
    vec2 sample_px;
    if (!locate_sample(at, px, sample_px, xn)) return false;
    bool ok;
    if (!map_sample(e, px, xn, xi, eta, ref, Z, ok)) return false;
    if (!ok) {
        atomicAdd(dropped_samples, 1u);
        return false;
    }
    return true;
}

// The sample of a pixel with 2..CANDIDATES candidates: each candidate is tested and the nearest
// owner kept (ties: the lower element index, as the oracle), an owner mapping outside the
// reference giving way to one behind it; false where none is kept (counted if one mapped
// outside). The single-candidate passes stay straight-line (llvmpipe runs them much faster
// without this loop).
bool map_nearest(ivec2 at, out int elem, out real xi, out real eta, out real2 ref, out real Z) {
    ivec2 pix = at / SS;
    uint n = candidate_count(pix);
    if (n < 2u || n > uint(CANDIDATES)) return false;
    real2 px, xn;
    vec2 sample_px;
    if (!locate_sample(at, px, sample_px, xn)) return false;
    elem = -1;
    Z = 0.0;
    bool dropped = false;
    real2 chosen_lo = real2(0.0);
    for (int k = 0; k < int(n); ++k) {
        int e = candidate(pix, k);
        if (!in_tight(e, sample_px, 0.0)) continue;
        real x, y, z;
        real2 r;
        bool ok;
        if (!map_sample(e, px, xn, x, y, r, z, ok)) continue;
        if (elem >= 0 && !(z < Z || (z == Z && e < elem))) continue;   // nearest, then lowest index
        if (!ok) {
            dropped = true;   // unless a farther owner maps inside the reference
            continue;
        }
        elem = e;
        xi = x; eta = y; ref = r; Z = z;
        chosen_lo = ref_lo;
    }
    ref_lo = chosen_lo;
    if (elem < 0) {
        if (dropped) atomicAdd(dropped_samples, 1u);
        return false;
    }
    return true;
}
