// The ray map of one camera: each sample's undistorted normalized coordinates, computed once
// per camera and supersampling (the exact mode reads it instead of undistorting per fragment).
// Stored as float32 (hi, lo) pairs so that FP64 builds keep double precision; NO_RAY marks a
// sample with no ray (beyond the distortion model's valid radius or not converged).
#include "camera.glsl"

#define NO_RAY 1e30  // keep in sync with deform.frag

uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_valid_r2;

out vec4 out_ray;

void main() {
    real2 px = real2(gl_FragCoord.xy) / real(SS) - 0.5;
    real2 xn;
    if (!undistort(pixel_to_normalized(px, u_intr), u_dist, u_valid_r2, xn)) {
        out_ray = vec4(NO_RAY);
        return;
    }
    vec2 hi = vec2(xn);
    out_ray = vec4(hi, vec2(xn - real2(hi)));
}
