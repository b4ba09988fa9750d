// Pass 2's records in modes exact and q4: what view.comp wrote for this view, the mesh's
// reference data uploaded once, and the candidate lists of pass 1 (list_reader.glsl).
// Per-view element records written by view.comp, float64 or float32 as `real`: exact: corners
// in the camera frame (12); q4: distorted pixel corners (8) and depths Z (4).
layout(std430, binding = BINDING_ELEMENTS) readonly buffer Elements { real elem_data[]; };
// the mesh, uploaded once per renderer (glsim.backends.gl.geometry): per node, reference-image
// coordinates (q4) or the undeformed position in the reference camera's frame (exact)
#if defined(MODE_Q4)
layout(std430, binding = BINDING_REF_UV) readonly buffer RefUV { real ref_uv[]; };
#else
layout(std430, binding = BINDING_REF_XR) readonly buffer RefXr { real ref_xr[]; };
#endif
#ifdef CAMERA_LOCAL
// float32 exact on a driver with float64: view.comp's RECORD_LOCAL records (32 per element)
layout(std430, binding = BINDING_LOCAL) readonly buffer Local { float elem_local[]; };
#endif
#ifdef REF_LOCAL
// float32 exact with a pinhole reference camera (glsim.backends.gl.geometry.ref_local_buffer):
// per element its reference-frame corners relative to their centre C (12), C (3), 0, and the
// reference pixel of C as hi (2) + lo (2), made in float64
layout(std430, binding = BINDING_REF_LOCAL) readonly buffer RefLocal { float ref_local[]; };
#endif
#ifdef REF_PINHOLE
// float64 exact with a pinhole reference camera (glsim.backends.gl.geometry.ref_pinhole_buffer):
// per element its reference-frame corners as (fx X + skew Y + cx Z, fy Y + cy Z, Z) (12)
layout(std430, binding = BINDING_REF_PINHOLE) readonly buffer RefPinhole { real ref_pinhole[]; };
#endif
#include "list_reader.glsl"
