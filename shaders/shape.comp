// The step's shape filter, once per load step (glsim.backends.gl.geometry.shape_candidates):
// whether some element may be zero-area, tiny or folded as numpy classifies it
// (glsim.stages.view.corner_areas and classify_shapes, float64 from the corners in the local
// frame), so that the host classifies a step's elements only where one may be.
//
// Per element, from its corners as uploaded (float64, or float32 in a float32 build: each
// coordinate within 2^-24 of numpy's), this build's area A = ½(|n1| + |n2|) and d = n1·n2
// (n1 = (P1 − P0) × (P2 − P0), n2 = (P2 − P0) × (P3 − P0)) and bounds on |A − A_numpy| and
// |d − d_numpy| (both against the exact values, k = this build's unit roundoff + float64's,
// δ the inputs' own rounding, L the longest of the three edge vectors): the edge vectors within
// e_v = 2kL + 4δ, a cross product within e_n = 2 e_v L + e_v² + 8kL², A within
// e_n + (10k + 4·2^-24)A (GLSL holds a double sqrt to float's precision only), d within
// e_n(|n1| + |n2|) + e_n² + 4k|n1||n2|; each bound used twice over (its own rounding).
// SHAPE (uint words, zero at the start):
//   [0] 1 if some d may be negative (folded, numpy's n1·n2 < 0);
//   [1] the complement of the bits of the least lower bound on an area (float32, rounded down;
//       atomicMax of complements: positive floats order as their bits);
//   [4 + b] the elements whose upper area bound (float32, rounded up) lies below 2^(b − SHAPE_BIAS)
//       and not below half that (frexp's exponent; the last bin: infinite).
#define SHAPE_BIAS 150
#define SHAPE_BINS 280

layout(local_size_x = 64) in;

layout(std430, binding = BINDING_QUADS) readonly buffer Quads { ivec4 quads[]; };
layout(std430, binding = BINDING_NODES) readonly buffer Nodes { real nodes[]; };   // 3 per node, local frame
layout(std430, binding = BINDING_SHAPE) buffer Shape { uint shape_words[]; };

uniform int u_count;   // elements

real3 node(int n) { return real3(nodes[3 * n], nodes[3 * n + 1], nodes[3 * n + 2]); }

real abs_max(real3 p) { return max(abs(p.x), max(abs(p.y), abs(p.z))); }

#ifdef FP64
// x ≥ 0 as a float32 no larger (down) or no smaller (up) than x
float round_down(real x) {
    float f32 = float(x);
    return (real(f32) > x && f32 > 0.0) ? uintBitsToFloat(floatBitsToUint(f32) - 1u) : f32;
}
float round_up(real x) {
    float f32 = float(x);
    return (real(f32) < x) ? uintBitsToFloat(floatBitsToUint(f32) + 1u) : f32;
}
#define INPUT_ROUNDING real(0.0)
#else
float round_down(real x) { return x; }
float round_up(real x) { return x; }
#define INPUT_ROUNDING ldexp(real(1.0), -24)
#endif

void main() {
    int e = int((gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) * gl_WorkGroupSize.x
                + gl_LocalInvocationID.x);
    if (e >= u_count) return;
    ivec4 q = quads[e];
    real3 P0 = node(q.x), P1 = node(q.y), P2 = node(q.z), P3 = node(q.w);
    precise real3 a = P1 - P0;
    precise real3 b = P2 - P0;
    precise real3 c = P3 - P0;
    precise real3 n1 = cross(a, b);
    precise real3 n2 = cross(b, c);
    precise real l1 = length(n1);
    precise real l2 = length(n2);
    precise real area = 0.5 * (l1 + l2);
    precise real d = dot(n1, n2);

#ifdef FP64
    real k = ldexp(real(1.0), -53) + ldexp(real(1.0), -53);
#else
    real k = ldexp(real(1.0), -24) + ldexp(real(1.0), -53);
#endif
    real delta = INPUT_ROUNDING * max(max(abs_max(P0), abs_max(P1)), max(abs_max(P2), abs_max(P3)));
    real L = max(length(a), max(length(b), length(c)));
    real ev = 2.0 * k * L + 4.0 * delta;
    L += ev;   // the exact edges' length, at most
    ev = 2.0 * k * L + 4.0 * delta;
    real en = 2.0 * ev * L + ev * ev + 8.0 * k * L * L;
    real eA = en + (10.0 * k + 4.0 * ldexp(real(1.0), -24)) * area;
    real m1 = l1 + en;
    real m2 = l2 + en;
    real ed = en * (m1 + m2) + en * en + 4.0 * k * m1 * m2;

    if (!(d > 2.0 * ed)) atomicOr(shape_words[0], 1u);
    real lo = area - 2.0 * eA;
    float low = lo > 0.0 ? round_down(lo) : 0.0;   // (NaN: 0)
    atomicMax(shape_words[1], ~floatBitsToUint(low));
    float high = round_up(area + 2.0 * eA);
    int ex;
    frexp(high, ex);
    int bin = (isinf(high) || isnan(high)) ? SHAPE_BINS - 1 : clamp(ex + SHAPE_BIAS, 0, SHAPE_BINS - 2);
    atomicAdd(shape_words[4 + bin], 1u);
}
