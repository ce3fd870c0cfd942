#version 330 core
// A texture as it is stored (level 0, no filtering across levels), for the UV inspector.
// sRGB textures are decoded by the sampler, so the colour is encoded again (as in resolve.frag).

uniform sampler2D image;

in vec2 v_pos;  // (u, v) over the viewport
out vec4 colour;

vec3 linear_to_srgb(vec3 x) {
    x = clamp(x, 0.0, 1.0);
    return mix(1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055, x * 12.92, lessThanEqual(x, vec3(0.0031308)));
}

void main() {
    colour = vec4(linear_to_srgb(textureLod(image, v_pos, 0.0).rgb), 1.0);
}
