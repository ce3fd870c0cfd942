#version 330 core
// Box-average the supersamples of each pixel in linear light, then encode to sRGB
// (PROTOCOL.md: 2 x 2 supersampling, sRGB before any metric).

uniform sampler2D samples;  // linear RGB, alpha = coverage; `factor` x larger than the output
uniform int factor;

layout(location = 0) out vec4 image;     // sRGB-encoded RGB, opaque
layout(location = 1) out float covered;  // 1 where any supersample is covered

vec3 linear_to_srgb(vec3 x) {
    x = clamp(x, 0.0, 1.0);
    return mix(1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, x * 12.92, lessThanEqual(x, vec3(0.0031308)));
}

void main() {
    ivec2 base = ivec2(gl_FragCoord.xy) * factor;
    vec4 sum = vec4(0.0);
    for (int y = 0; y < factor; ++y)
        for (int x = 0; x < factor; ++x)
            sum += texelFetch(samples, base + ivec2(x, y), 0);
    vec4 mean = sum / float(factor * factor);
    image = vec4(linear_to_srgb(mean.rgb), 1.0);
    covered = mean.a > 0.0 ? 1.0 : 0.0;
}
