// Mode fast, one sample of a triangle of deform.vert (as fast.geom passes it on, or as
// fasttriangles.glsl's record keeps it): the perspective-correct interpolation of
// glsim.backends.cpu._fast in float32, at the sample's exact pixel point q, with barycentrics
// from edge functions relative to vertex 0. `at`: the sample's texel in the target of SS x SS
// samples per pixel; uv the vertices as projected (px), ref their reference points, xe their
// (xi, eta), z their depths. Gives the reference point, (xi, eta) and the depth Z.
void fast_sample(ivec2 at, vec2 uv[3], vec2 ref3[3], vec2 xe3[3], float z[3], out real2 ref, out real xi,
                 out real eta, out float Z) {
    vec2 q = (vec2(at) + 0.5) / float(SS) - 0.5;
    vec2 a = uv[0], ab = uv[1] - a, ac = uv[2] - a, aq = q - a;
    float den = ab.x * ac.y - ab.y * ac.x;
    float l1 = (aq.x * ac.y - aq.y * ac.x) / den, l2 = (ab.x * aq.y - ab.y * aq.x) / den;
    vec3 w = vec3(1.0 - l1 - l2, l1, l2) / vec3(z[0], z[1], z[2]);
    float sw = w.x + w.y + w.z;
    Z = 1.0 / sw;
    w *= Z;
    ref = real2(w.x * ref3[0] + w.y * ref3[1] + w.z * ref3[2]);
    vec2 xe = w.x * xe3[0] + w.y * xe3[1] + w.z * xe3[2];
    xi = xe.x;
    eta = xe.y;
}
