// Procedural reference speckle: the Boolean model of glsim/scene/speckle.py (Dots) evaluated exactly
// at uv, so no texture interpolation enters the image. Same smoothstep edge profile and
// max-darkness union as speckle.evaluate; dots found through a uniform grid (speckle.dot_grid)
// whose cells are at least the dots' reach wide, so the 3 x 3 cells around uv hold them all.

// per dot, sorted by cell: centre relative to its cell's corner (u, v) and radius, px
layout(std430, binding = BINDING_DOTS) readonly buffer Dots { float dot_data[]; };
// per cell (row-major, nx per row): first dot, number of dots
layout(std430, binding = BINDING_DOT_CELLS) readonly buffer Cells { int cell_data[]; };

uniform vec2 u_grid_origin_hi;   // grid origin split in two floats (hi + lo) for FP64 builds
uniform vec2 u_grid_origin_lo;
uniform float u_grid_cell;
uniform ivec2 u_grid_dims;
uniform float u_dot_edge;
uniform float u_dot_black;
uniform float u_dot_white;

float dot_profile(float r, float radius) {
    if (u_dot_edge == 0.0) return r < radius ? 1.0 : 0.0;
    float x = clamp(0.5 - (r - radius) / u_dot_edge, 0.0, 1.0);
    return x * x * (3.0 - 2.0 * x);
}

float sample_ref(real2 uv) {
    real2 g = (uv - real2(u_grid_origin_hi) - real2(u_grid_origin_lo)) / real(u_grid_cell);
    ivec2 c = ivec2(floor(g));
    float darkness = 0.0;
    for (int dj = -1; dj <= 1; ++dj) {
        for (int di = -1; di <= 1; ++di) {
            ivec2 k = c + ivec2(di, dj);
            if (any(lessThan(k, ivec2(0))) || any(greaterThanEqual(k, u_grid_dims))) continue;
            int cell = k.y * u_grid_dims.x + k.x;
            // uv relative to this cell's corner: small numbers, exact enough in float
            vec2 local = vec2((g - real2(k)) * real(u_grid_cell));
            int first = cell_data[2 * cell], n = cell_data[2 * cell + 1];
            for (int m = first; m < first + n; ++m) {
                vec2 d = local - vec2(dot_data[3 * m], dot_data[3 * m + 1]);
                darkness = max(darkness, dot_profile(length(d), dot_data[3 * m + 2]));
            }
        }
    }
    return u_dot_white - (u_dot_white - u_dot_black) * darkness;
}
