// Pixel integration: box filter over the SS x SS samples of each pixel.
uniform sampler2D u_samples;

out float out_grey;

void main() {
    ivec2 base = ivec2(gl_FragCoord.xy) * SS;
    float acc = 0.0;
    for (int j = 0; j < SS; ++j)
        for (int i = 0; i < SS; ++i)
            acc += texelFetch(u_samples, base + ivec2(i, j), 0).r;
    out_grey = acc / float(SS * SS);
}
