// Per-element geometry of one view, on the GPU: the GLSL twin of glsim/stages/view.py
// (cover_rectangles, footprint_box, grazing) and of the transform in glsim/stages/geometry.py.
// Needs camera.glsl and the loader's precision macros.
//
// The mesh is uploaded once per renderer (connectivity, reference data per node), the deformed
// nodes once per load step (relative to the mesh's origin, float64 or float32 as `real`); per
// view only uniforms change: X_cam = R (X - origin) + t.

layout(std430, binding = BINDING_QUADS) readonly buffer Quads { ivec4 quads[]; };
layout(std430, binding = BINDING_NODES) readonly buffer Nodes { real nodes[]; };        // 3 per node, local frame
// element problems found on the GPU for the warnings: two bitsets of u_flag_words words
// (grazing, does not project) and "any set" markers; cleared by the backend when read
layout(std430, binding = BINDING_FLAGS) buffer Flags { uint flag_any[4]; uint flag_bits[]; };

uniform real u_rot[9];       // R, row-major
uniform real u_trans[3];     // R origin + t (mm)
uniform real u_near;         // glsim.stages.view.NEAR_MM
uniform real u_grazing_cos;  // glsim.stages.view.GRAZING_COS
uniform int u_flag_words;

real3 node_camera(int n) {
    real3 x = real3(nodes[3 * n], nodes[3 * n + 1], nodes[3 * n + 2]);
    return real3(u_rot[0] * x.x + u_rot[1] * x.y + u_rot[2] * x.z + u_trans[0],
                 u_rot[3] * x.x + u_rot[4] * x.y + u_rot[5] * x.z + u_trans[1],
                 u_rot[6] * x.x + u_rot[7] * x.y + u_rot[8] * x.z + u_trans[2]);
}

// The corners of element e in the camera frame (mm).
void element_corners(int e, out real3 P[4]) {
    ivec4 q = quads[e];
    #pragma unroll
    for (int i = 0; i < 4; ++i) P[i] = node_camera(q[i]);
}

// All four corners in front of the camera and inside the valid radius (camera.glsl's test).
bool corners_projectable(real3 P[4], real valid_r2) {
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        if (!(P[i].z > 0.0)) return false;
        real2 xn = P[i].xy / P[i].z;
        if (!(dot(xn, xn) < valid_r2)) return false;
    }
    return true;
}

bool corners_behind(real3 P[4]) {
    return P[0].z <= u_near && P[1].z <= u_near && P[2].z <= u_near && P[3].z <= u_near;
}

// Seen at more than GRAZING_DEG from the normal (glsim.stages.view.grazing).
bool is_grazing(real3 P[4]) {
    real3 v = 0.25 * (P[0] + P[1] + P[2] + P[3]);
    real3 n = cross(P[2] - P[0], P[3] - P[1]);
    real d = length(n) * length(v);
    real c = d > 0.0 ? abs(dot(n, v)) / d : 0.0;
    return c < u_grazing_cos;
}

void set_flag(int k, int e) {
    atomicOr(flag_any[k], 1u);
    atomicOr(flag_bits[k * u_flag_words + (e >> 5)], 1u << uint(e & 31));
}

// The camera-dependent problems of element e: grazing (the host leaves out zero-area, tiny and
// folded elements: glsim.backends.gl.geometry), and not projectable while not wholly behind the
// camera.
void record_flags(int e, real3 P[4], bool projectable, bool behind) {
    if (is_grazing(P)) set_flag(0, e);
    if (!projectable && !behind) set_flag(1, e);
}

#ifdef COVER
// ---- conservative covers (glsim.stages.view.cover_rectangles) --------------------------------
#define COVER_PAD_PX 0.125
#define COVER_FINE_INTERVALS 8
#define COVER_COARSE_SAG_PX 0.015625
#define COVER_BOUNDARY_INTERVALS 8
#define FAR_AWAY 1e30

#define TIGHT_PAD_PX 0.0009765625

uniform real u_intr[5];
uniform real u_dist[12];
uniform real u_ray_r;        // glsim.stages.view.ray_radius; < 0: unbounded
uniform vec2 u_size;
uniform real u_cover_grow;   // the covers also hold squares of this half-width around their points
uniform real u_extra_sag;    // px added to every sagitta: quadratic elements' pieces (their chord error); else 0

real2 to_pixels(real2 xn) { return normalized_to_pixel(distort(xn, u_dist), u_intr); }

// Running extent of points along the unit axes a and b = (-a.y, a.x).
struct Extent { real2 a; real lo_a, hi_a, lo_b, hi_b, umax; };

Extent extent_start(real2 a) { return Extent(a, FAR_AWAY, -FAR_AWAY, FAR_AWAY, -FAR_AWAY, 0.0); }

void extent_add(inout Extent x, real2 p) {
    real pa = dot(p, x.a), pb = x.a.x * p.y - x.a.y * p.x;
    x.lo_a = min(x.lo_a, pa); x.hi_a = max(x.hi_a, pa);
    x.lo_b = min(x.lo_b, pb); x.hi_b = max(x.hi_b, pb);
    x.umax = max(x.umax, max(abs(p.x), abs(p.y)));
}

// The cover rectangle (padded for the rasterizer's snapping, COVER_PAD_PX, and grown by
// u_cover_grow) and the tight one (padded for float32 rounding only, TIGHT_PAD_PX): corners
// along the axes, and (a, lo_a, hi_a), (lo_b, hi_b) for candidates.glsl.
void extent_rect(Extent x, real sag, out vec2 rect[4], out vec4 tight[2]) {
    sag += u_extra_sag;
    real round_off = real(1e-6lf) * (x.umax + real(u_size.x) + real(u_size.y));
    real2 a = x.a, b = real2(-x.a.y, x.a.x);
    real pad = 2.0 * sag + COVER_PAD_PX + round_off + u_cover_grow * (abs(a.x) + abs(a.y));
    real la = x.lo_a - pad, ha = x.hi_a + pad, lb = x.lo_b - pad, hb = x.hi_b + pad;
    rect[0] = vec2(la * a + lb * b);
    rect[1] = vec2(ha * a + lb * b);
    rect[2] = vec2(ha * a + hb * b);
    rect[3] = vec2(la * a + hb * b);
    real t = 2.0 * sag + TIGHT_PAD_PX + round_off;
    tight[0] = vec4(vec2(a), float(x.lo_a - t), float(x.hi_a + t));
    tight[1] = vec4(float(x.lo_b - t), float(x.hi_b + t), 0.0, 0.0);
}

const ivec2 COVER_SEGMENTS[6] = ivec2[6](ivec2(0, 1), ivec2(1, 2), ivec2(2, 3), ivec2(3, 0), ivec2(0, 2), ivec2(1, 3));

// Elements whose corners all project: corners and segment midpoints, or, where a midpoint
// strays more than COVER_COARSE_SAG_PX from its chord, the segments sampled finely.
void projectable_cover(real3 P[4], out vec2 rect[4], out vec4 tight[2]) {
    real2 xn[4], uvc[4];
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        xn[i] = P[i].xy / P[i].z;
        uvc[i] = to_pixels(xn[i]);
    }
    real2 a = (uvc[1] - uvc[0]) + (uvc[2] - uvc[3]);
    real n = length(a);
    a = n > 0.0 ? a / n : real2(1.0, 0.0);
    Extent x = extent_start(a);
    real sag = 0.0;
    #pragma unroll
    for (int i = 0; i < 4; ++i) extent_add(x, uvc[i]);
    #pragma unroll
    for (int s = 0; s < 6; ++s) {
        const ivec2 ij = COVER_SEGMENTS[s];
        real2 m = to_pixels(0.5 * (xn[ij.x] + xn[ij.y]));
        sag = max(sag, length(m - 0.5 * (uvc[ij.x] + uvc[ij.y])));
        extent_add(x, m);
    }
    if (sag > COVER_COARSE_SAG_PX) {
        sag = 0.0;
        #pragma unroll
        for (int s = 0; s < 6; ++s) {
            const ivec2 ij = COVER_SEGMENTS[s];
            real2 d = xn[ij.y] - xn[ij.x];
            real2 prev = uvc[ij.x];
            for (int k = 1; k <= COVER_FINE_INTERVALS; ++k) {
                real2 p = to_pixels(xn[ij.x] + (real(k) / real(COVER_FINE_INTERVALS)) * d);
                real2 m = to_pixels(xn[ij.x] + ((real(k) - 0.5) / real(COVER_FINE_INTERVALS)) * d);
                sag = max(sag, length(m - 0.5 * (prev + p)));
                extent_add(x, p);
                prev = p;
            }
        }
    }
    extent_rect(x, sag, rect, tight);
}

// Elements that do not project: the footprint box of their rays (view.py footprint_box),
// its boundary pulled radially onto the disc of u_ray_r, distorted. False: never seen.
bool unprojectable_cover(real3 P[4], out vec2 rect[4], out vec4 tight[2]) {
    if (u_ray_r < 0.0) {  // nothing bounds the rays: the whole image
        rect[0] = vec2(-0.5, -0.5);
        rect[1] = vec2(u_size.x - 0.5, -0.5);
        rect[2] = vec2(u_size.x - 0.5, u_size.y - 0.5);
        rect[3] = vec2(-0.5, u_size.y - 0.5);
        tight[0] = vec4(1.0, 0.0, -1.0, u_size.x);
        tight[1] = vec4(-1.0, u_size.y, 0.0, 0.0);
        return true;
    }
    real2 lo = real2(FAR_AWAY), hi = real2(-FAR_AWAY);
    #pragma unroll
    for (int i = 0; i < 4; ++i) {
        if (!(P[i].z > 0.0)) continue;
        real2 p = P[i].xy / P[i].z;
        lo = min(lo, p);
        hi = max(hi, p);
        #pragma unroll
        for (int j = 0; j < 4; ++j) {
            if (P[j].z > 0.0) continue;
            real2 d = P[i].z * P[j].xy - P[j].z * P[i].xy;   // the segment's crossing: a direction
            bool zero = d.x == 0.0 && d.y == 0.0;
            if (d.x < 0.0 || zero) lo.x = -FAR_AWAY;
            if (d.y < 0.0 || zero) lo.y = -FAR_AWAY;
            if (d.x > 0.0 || zero) hi.x = FAR_AWAY;
            if (d.y > 0.0 || zero) hi.y = FAR_AWAY;
        }
    }
    lo = max(lo, real2(-u_ray_r));
    hi = min(hi, real2(u_ray_r));
    if (!(lo.x <= hi.x && lo.y <= hi.y)) return false;
    real2 c[4] = real2[4](lo, real2(hi.x, lo.y), hi, real2(lo.x, hi.y));
    Extent x = extent_start(real2(1.0, 0.0));
    real sag = 0.0;
    const int N = 2 * COVER_BOUNDARY_INTERVALS;
    real2 first, prev, mid;
    #pragma unroll
    for (int s = 0; s < 4; ++s) {
        for (int k = 0; k < N; ++k) {
            real2 q = c[s] + (real(k) / real(N)) * (c[(s + 1) & 3] - c[s]);
            real r = length(q);
            if (r > u_ray_r) q *= u_ray_r / r;
            real2 p = to_pixels(q);
            extent_add(x, p);
            if ((k & 1) == 1) {
                mid = p;
            } else {
                if (s > 0 || k > 0) sag = max(sag, length(mid - 0.5 * (prev + p)));
                else first = p;
                prev = p;
            }
        }
    }
    sag = max(sag, length(mid - 0.5 * (prev + first)));
    extent_rect(x, sag, rect, tight);
    return true;
}
#endif
