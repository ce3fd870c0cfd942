#version 330 core
// How the app shows two renders of the same view in one picture.
// mode 0: wipe, `first` left of `split` (a fraction of the width), `second` right of it, a line
//         between them; mode 1: difference heatmap, |first - second| (sRGB, largest channel)
//         times `gain` through a black-red-yellow-white ramp.

uniform sampler2D first;
uniform sampler2D second;
uniform int mode;
uniform float split;
uniform float gain;

in vec2 v_pos;
out vec4 colour;

vec3 heat(float t) {
    t = clamp(t, 0.0, 1.0);
    return clamp(vec3(3.0 * t, 3.0 * t - 1.0, 3.0 * t - 2.0), 0.0, 1.0);
}

void main() {
    vec3 a = texture(first, v_pos).rgb;
    vec3 b = texture(second, v_pos).rgb;
    if (mode == 0) {
        float line = abs(v_pos.x - split) * float(textureSize(first, 0).x);
        colour = vec4(line < 1.0 ? vec3(1.0, 0.8, 0.2) : (v_pos.x < split ? a : b), 1.0);
    } else {
        vec3 d = abs(a - b);
        colour = vec4(heat(gain * max(d.r, max(d.g, d.b))), 1.0);
    }
}
