// Vignetting (glsim/effects/vignetting.py): the irradiance times the camera's gain, per pixel
// (vignette.frag, vignette.comp).
layout(binding = SAMPLER_SRC) uniform sampler2D u_src;
layout(binding = SAMPLER_GAIN) uniform sampler2D u_gain;   // R32F (H, W): the float64 gain rounded to float32

float vignette(ivec2 p) {
    return texelFetch(u_src, p, 0).r * texelFetch(u_gain, p, 0).r;
}
