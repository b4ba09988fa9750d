// The grey value of a mapped sample: the reference image interpolated at its reference point
// (interp.glsl) and, with LIGHTING, combined with the Phong intensity of the surface there
// (shade.glsl).
#include "interp.glsl"
#ifdef LIGHTING
#include "camera.glsl"
#include "bilinear.glsl"
#include "view.glsl"
#ifdef QUADRATIC
#include "quadratic.glsl"
#endif
#include "shade.glsl"
// per element: the step's unit corner normals in the world frame (12), float32, uploaded once
// per step (glsim.backends.gl.geometry.GeometryBuffers.normals); rotated here by u_rot
layout(std430, binding = BINDING_NORMALS) readonly buffer Normals { float corner_normals[]; };

// Phong intensity at (xi, eta) of element e: surface point and interpolated unit normal, in
// the camera frame.
float light_at(int e, real xi, real eta) {
    vec3 X = vec3(0.0), N = vec3(0.0);
#ifdef QUADRATIC
    // e is a piece of a curved patch and (xi, eta) the patch's: the point on the patch, the
    // normal interpolated over the piece holding it (glsim.backends.cpu._shade)
    int pid, ci, cj;
    piece_cell(e, pid, ci, cj);
    real Nq[9];
    q9_shape(xi, eta, Nq);
    #pragma unroll
    for (int i = 0; i < 9; ++i) X += float(Nq[i]) * vec3(patch_camera(pid, i));
    real n2 = real(PIECES);
    real cx = clamp(floor((xi + 1.0) * n2 / 2.0), 0.0, n2 - 1.0), cy = clamp(floor((eta + 1.0) * n2 / 2.0), 0.0, n2 - 1.0);
    e = pid * PIECES * PIECES + int(cy) * PIECES + int(cx);
    vec4 w = vec4(shape_functions((xi + 1.0) * n2 - 2.0 * cx - 1.0, (eta + 1.0) * n2 - 2.0 * cy - 1.0));
    for (int i = 0; i < 4; ++i) {
        int b = e * 12 + 3 * i;
        N += w[i] * vec3(corner_normals[b], corner_normals[b + 1], corner_normals[b + 2]);
    }
#else
    vec4 w = vec4(shape_functions(xi, eta));
    ivec4 q = quads[e];
    for (int i = 0; i < 4; ++i) {
        int b = e * 12 + 3 * i;
        X += w[i] * vec3(node_camera(q[i]));
        N += w[i] * vec3(corner_normals[b], corner_normals[b + 1], corner_normals[b + 2]);
    }
#endif
    // u_rot is row-major; mat3() fills columns, so this is R
    N = transpose(mat3(float(u_rot[0]), float(u_rot[1]), float(u_rot[2]), float(u_rot[3]), float(u_rot[4]),
                       float(u_rot[5]), float(u_rot[6]), float(u_rot[7]), float(u_rot[8]))) * N;
    float n = length(N);
    return phong(X, n > 0.0 ? N / n : vec3(0.0));
}
#endif

// The grey value of element e's sample at (xi, eta), which maps to ref in the reference image.
float shade_sample(int e, real xi, real eta, real2 ref) {
    float grey = sample_ref(ref);
#ifdef LIGHTING
    grey = combine(grey, light_at(e, xi, eta));
#endif
    return grey;
}
