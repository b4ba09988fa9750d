// Sensor noise (sensor_noise.glsl) as a compute pass.
#include "comp_grey.glsl"
#include "sensor_noise.glsl"

void main() {
    if (PASS_OUTSIDE) return;
    PASS_WRITE(noisy(PASS_PIXEL));
}
