// render.subsamples = "newton" (mode exact, SS > 1), at pixel resolution W×H.
//
// Pass 2a (lists.vert on classify.frag's single-candidate layer, early depth test, before the
// per-sample passes): the pixel's centre is mapped exactly (the ray map at 1 spp; both roots
// in closed form, the nearest in range kept) and each sub-sample is placed by Gauss-Newton
// steps from it on the sub-sample's own ray until a step is at most SUBSAMPLE_TOL. A pixel is
// done here only when every sub-sample is decided without the tie rule: centre and
// sub-samples strictly inside the element (beyond NEAR_TOL of its edges), the patch's other
// root beyond OTHER_ROOT_RANGE, rays present, Newton converged within SUBSAMPLE_STEPS. Done
// pixels write the box-filtered grey (and mean depth) and mark their count LIST_DONE; the
// others are left to the per-sample passes, which skip done pixels, and then to the box filter
// (downsample.frag with SKIP_DONE), which leaves done pixels as this pass wrote them.
layout(early_fragment_tests) in;
#include "sample_map.glsl"
#include "shading.glsl"
#include "frag_targets.glsl"

#ifdef FP64
#define SUBSAMPLE_TOL 1e-7lf
#else
#define SUBSAMPLE_TOL 1e-4
#endif
#define SUBSAMPLE_STEPS 3
#define OTHER_ROOT_RANGE 3.0

layout(binding = SAMPLER_CENTRE_RAYS) uniform RAY_SAMPLER u_centre_rays;   // rays.frag at 1 spp
uniform float u_background;

void main() {
    ivec2 pix = ivec2(gl_FragCoord.xy);
    int e = int(imageLoad(u_cand_list, ivec3(pix, 0)).x);
    real3 P[4];
    element_camera(e, P);
    real4 Pz = real4(P[0].z, P[1].z, P[2].z, P[3].z);
    real2 xc;
    bool centre_ray = ray_at(u_centre_rays, pix, xc);
    real2 p[4];
    projected_corners(e, P, xc, ray_lo, p);
    real xs[2], es[2];
    bool ok[2];
    invert_closed(p, real2(0.0), xs, es, ok);
    real z0 = dot(shape_functions(xs[0], es[0]), Pz), z1 = dot(shape_functions(xs[1], es[1]), Pz);
    bool in0 = ok[0] && z0 > 0.0 && in_range(xs[0], es[0]);
    bool in1 = ok[1] && z1 > 0.0 && in_range(xs[1], es[1]);
    // the nearer root r and the other one, selected (a variable index into xs would put it in
    // NVIDIA's float32 memory: README, "glsim check")
    bool r0 = in0 && (!in1 || z0 <= z1);
    real xr = r0 ? xs[0] : xs[1], er = r0 ? es[0] : es[1];
    bool other_far = !(r0 ? ok[1] : ok[0]) || max(abs(r0 ? xs[1] : xs[0]), abs(r0 ? es[1] : es[0])) > OTHER_ROOT_RANGE;
    bool done = centre_ray && (r0 ? in0 : in1) && other_far && !near_edge(xr, er);
    float acc = 0.0, zacc = 0.0, zn = 0.0;
    uint dropped = 0u;
    for (int j = 0; j < SS; ++j)
        for (int i = 0; i < SS; ++i) {
            real2 xn;
            bool has_ray = ray_at(u_rays, pix * SS + ivec2(i, j), xn);
            projected_corners(e, P, xn, ray_lo, p);
            real xi = xr, eta = er;
            bool converged = false;
            for (int it = 0; it < SUBSAMPLE_STEPS && !converged; ++it) {
                real dx, dy, det;
                newton_step(p, xi, eta, real2(0.0), dx, dy, det);
                xi += dx;
                eta += dy;
                converged = det != 0.0 && max(abs(dx), abs(dy)) <= SUBSAMPLE_TOL;
            }
            real Z = dot(shape_functions(xi, eta), Pz);
            done = done && has_ray && converged && Z > 0.0 && in_range(xi, eta) && !near_edge(xi, eta);
            real2 ref;
            float grey = u_background;
            if (exact_reference(e, xi, eta, ref) && inside_reference(ref)) {
                grey = shade_sample(e, xi, eta, ref);
                zacc += float(Z);
                zn += 1.0;
            } else {
                dropped += 1u;
            }
            acc += grey;
        }
    if (!done) discard;
    if (dropped > 0u) atomicAdd(dropped_samples, dropped);  // counted for warn_dropped
    imageStore(u_cand_count, pix, uvec4(LIST_DONE));
    out_grey = acc / float(SS * SS);
#ifdef DEPTH_OUT
    out_depth = zn > 0.0 ? zacc / zn : 0.0;
#endif
}
