// The ray map of one camera: each sample's undistorted normalized coordinates, computed once
// per camera and supersampling (the exact mode reads it instead of undistorting per fragment;
// raymap.glsl reads it). Output by consumer: RAY_BITS, the float64 pair bit for bit (RGBA32UI);
// RAY_SPLIT (float32 builds on a float64 driver), float32 (hi, lo) pairs split with bit
// operations (hilo.glsl); otherwise float32 (xn, 0, 0). NO_RAY marks a sample with no ray
// (beyond the distortion model's valid radius or not converged).
#include "camera.glsl"
#include "hilo.glsl"

#define NO_RAY 1e30  // raymap.glsl's test

uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;

#ifdef RAY_BITS
out uvec4 out_ray;
#else
out vec4 out_ray;
#endif

void main() {
    // the sample's pixel coordinates: exact (gl_FragCoord is a half-integer, SS a power of two
    // or small), as glsim.scene.camera.pixel_grid's
#ifdef APERTURE
    real2 px = aperture_sample(ivec2(gl_FragCoord.xy));
#else
    precise real2 px = real2(gl_FragCoord.xy) / real(SS) - 0.5;
#endif
    real2 xn;
    bool ok = undistort(pixel_to_normalized(px, u_intr), u_dist, u_valid_r2, xn);
#if defined(RAY_BITS)
    if (!ok) xn = real2(NO_RAY);
    out_ray = uvec4(unpackDouble2x32(xn.x), unpackDouble2x32(xn.y));
#elif defined(RAY_SPLIT)
    out_ray = ok ? split_double2(xn) : vec4(NO_RAY);
#else
    out_ray = ok ? vec4(xn, 0.0, 0.0) : vec4(NO_RAY);
#endif
}
