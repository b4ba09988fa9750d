// Mode fast: each triangle passed on to fast.frag (fastgeom.glsl).
#include "fastgeom.glsl"

void main() {
    emit_triangle();
}
