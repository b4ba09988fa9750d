// Phong lighting (paper §2.2.1, eq. 13 summed over lights): the GLSL twin of glsim/effects/lighting.py
// (same names and formula). Float only (GLSL pow is float-only). Camera frame, mm, camera at
// the origin; grey levels in fractions of full scale. MAX_LIGHTS (>= 1) is #defined by the
// loader; a light with u_light_intensity = 0 contributes nothing. LIGHT_MULTIPLICATIVE picks
// grey * I in combine(), additive grey + I otherwise.
//
//   I = I_a + sum_i spot_i * I_i / (1 + k_i d_i^2) * (k_r max(N.L_i, 0) + k_s [N.L_i > 0] max(R_i.V, 0)^r)

uniform vec3 u_light_pos[MAX_LIGHTS];          // camera frame, mm
uniform vec3 u_light_dir[MAX_LIGHTS];          // unit spot axis; (0, 0, 0) = point light
uniform float u_light_intensity[MAX_LIGHTS];   // I_i, fraction of full scale
uniform float u_light_att[MAX_LIGHTS];         // k of 1 / (1 + k d^2), 1/mm^2
uniform float u_light_cos_cutoff[MAX_LIGHTS];  // cos(spot half-angle)
uniform float u_light_cos_inner[MAX_LIGHTS];   // cos(cutoff - edge); = cos_cutoff for a hard edge
uniform float u_ambient;                       // I_a
uniform float u_kr;                            // k_r, diffuse reflection coefficient
uniform float u_ks;                            // k_s, specular reflection coefficient
uniform float u_shininess;                     // r

// smoothstep(cos_cutoff, cos_inner, cos_theta) for a smooth edge, [cos_theta >= cos_cutoff] for a hard one.
float spot_factor(float cos_theta, float cos_cutoff, float cos_inner) {
    if (cos_inner > cos_cutoff) {
        float s = clamp((cos_theta - cos_cutoff) / (cos_inner - cos_cutoff), 0.0, 1.0);
        return s * s * (3.0 - 2.0 * s);
    }
    return cos_theta >= cos_cutoff ? 1.0 : 0.0;
}

vec3 shade_normalize(vec3 v, out float len) {
    len = length(v);
    return len > 0.0 ? v / len : vec3(0.0);
}

// log(1 - s) for 0 <= s < 1, accurate for small s (GLSL has no log1p): 2 atanh(-z) with
// z = s / (2 - s), four terms of its series for s <= 1/4 (relative error < 3e-8).
float log1m(float s) {
    if (s > 0.25) return log(1.0 - s);
    float z = s / (2.0 - s), z2 = z * z;
    return -2.0 * z * (1.0 + z2 * (1.0 / 3.0 + z2 * (0.2 + z2 * (1.0 / 7.0))));
}

// Illumination at the camera-frame point X with normal N (normalised here; N = 0: ambient only).
// The specular power is exp(r log(1 - s)) with s = |R - V|^2 / 2 = 1 - R.V: the same number
// as pow(R.V, r), but it keeps its relative accuracy in float at the highlight.
float phong(vec3 X, vec3 N) {
    float len;
    N = shade_normalize(N, len);
    vec3 V = shade_normalize(-X, len);
    if (dot(N, V) < 0.0) N = -N;                // thin shells are seen from either side
    float I = u_ambient;
    for (int i = 0; i < MAX_LIGHTS; ++i) {
        float d;
        vec3 L = shade_normalize(u_light_pos[i] - X, d);
        float nl = dot(N, L);
        vec3 RmV = 2.0 * nl * N - L - V;        // R - V, R the mirrored light direction
        float s = 0.5 * dot(RmV, RmV);           // 1 - R.V
        float spec = (nl > 0.0 && s < 1.0) ? exp(u_shininess * log1m(s)) : 0.0;
        float spot = dot(u_light_dir[i], u_light_dir[i]) > 0.0
            ? spot_factor(dot(-L, u_light_dir[i]), u_light_cos_cutoff[i], u_light_cos_inner[i]) : 1.0;
        float att = u_light_intensity[i] / (1.0 + u_light_att[i] * d * d);
        I += spot * att * (u_kr * max(nl, 0.0) + u_ks * spec);
    }
    return I;
}

// Lit grey level, not clipped (saturation is clipped and reported at quantisation).
float combine(float grey, float I) {
#ifdef LIGHT_MULTIPLICATIVE
    return grey * I;
#else
    return grey + I;
#endif
}
