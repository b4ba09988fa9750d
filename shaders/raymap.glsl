// Reading the ray map (rays.frag): per sample the undistorted normalized coordinates xn of its
// ray. FP64 builds read the two float64 bit for bit (RGBA32UI, unpackDouble2x32 of x and y), so
// every sample's ray is the oracle's (glsim.scene.camera.pixel_to_normalized, undistort);
// float32 builds read (hi, lo) float32 pairs (RGBA32F) and keep the low half apart in ray_lo.
// A sample without a ray (rays.frag's NO_RAY) reads x >= 1e30.
#ifdef FP64
#define RAY_SAMPLER usampler2D
#else
#define RAY_SAMPLER sampler2D
#endif

real2 ray_lo = real2(0.0);   // float32 builds: the last ray's low half (CAMERA_LOCAL)

// The ray of texel p of map t; false where the sample has none.
bool ray_at(RAY_SAMPLER t, ivec2 p, out real2 xn) {
#ifdef FP64
    uvec4 w = texelFetch(t, p, 0);
    xn = real2(packDouble2x32(w.xy), packDouble2x32(w.zw));
    ray_lo = real2(0.0);
    return xn.x < 1e30lf;
#else
    vec4 texel = texelFetch(t, p, 0);
    xn = texel.xy;
    ray_lo = texel.zw;
    return texel.x < 1e30;
#endif
}
