// Sensor noise (sensor_noise.glsl) as a fragment pass.
#include "frag_grey.glsl"
#include "sensor_noise.glsl"

void main() {
    PASS_WRITE(noisy(PASS_PIXEL));
}
