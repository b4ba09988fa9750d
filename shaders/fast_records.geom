// Mode fast in the compute pixel stage: each triangle's record kept (fasttriangles.glsl) and the
// triangle passed on to fast_ids.frag with its index (g_tri), which is all that pass writes.
#include "fastgeom.glsl"
#include "fasttriangles.glsl"

void main() {
    int b = FAST_RECORD * gl_PrimitiveIDIn;
    for (int i = 0; i < 3; ++i) {
        fast_rec[b + 2 * i] = v_uv[i].x;
        fast_rec[b + 2 * i + 1] = v_uv[i].y;
        fast_rec[b + 6 + 2 * i] = v_ref[i].x;
        fast_rec[b + 7 + 2 * i] = v_ref[i].y;
        fast_rec[b + 12 + 2 * i] = v_xe[i].x;
        fast_rec[b + 13 + 2 * i] = v_xe[i].y;
        fast_rec[b + 18 + i] = v_depth[i];
    }
    fast_rec[b + 21] = intBitsToFloat(v_elem[0]);
    emit_triangle();
}
