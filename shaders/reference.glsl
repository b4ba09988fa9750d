// The reference image's extent, and the count of samples that hit the specimen but map outside
// it (glsim.stages.view.warn_dropped; the backend resets it before each pass).
uniform vec2 u_ref_size;  // reference image W, H (px)
layout(std430, binding = BINDING_DROPPED) buffer Dropped { uint dropped_samples; };

bool inside_reference(real2 ref) {
    return !(ref.x < -0.5 || ref.y < -0.5 || ref.x > real(u_ref_size.x) - 0.5 || ref.y > real(u_ref_size.y) - 0.5);
}
