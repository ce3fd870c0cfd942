#version 450 core
// The PROTOCOL.md sampler, the GLSL twin of geoscaler/texture.py.
// The texture is GL_SRGB8_ALPHA8 with a mip chain built like texture.py's (2 x 2 box averages in
// linear light), so every fetch is decoded to linear light by the hardware before filtering.
// Trilinear filtering, repeat addressing; the level of detail is log2 of the larger singular
// value of the screen-space UV Jacobian in texels, with the Jacobian taken exactly: u/w, v/w and
// 1/w are affine across a triangle, so their finite differences are exact derivatives.

uniform sampler2D base_color;
uniform bool textured;
uniform vec3 base_color_factor;  // linear RGB
uniform float max_level;         // mip levels - 1

in vec2 v_uv;
noperspective in vec3 v_uvw;

out vec4 colour;  // linear RGB, alpha 1 marks coverage

float level_of_detail() {
    vec3 ddx = dFdxFine(v_uvw);
    vec3 ddy = dFdyFine(v_uvw);
    vec2 uv = v_uvw.xy / v_uvw.z;
    vec2 size = vec2(textureSize(base_color, 0));
    vec2 dx = (ddx.xy - uv * ddx.z) / v_uvw.z * size;  // d(u, v)/dx in texels
    vec2 dy = (ddy.xy - uv * ddy.z) / v_uvw.z * size;
    float frobenius = dot(dx, dx) + dot(dy, dy);
    float det = dx.x * dy.y - dy.x * dx.y;
    float gap = sqrt(max(frobenius * frobenius - 4.0 * det * det, 1e-20));
    return 0.5 * log2(max(0.5 * (frobenius + gap), 1e-30));
}

void main() {
    vec3 rgb = base_color_factor;
    if (textured) {
        float lod = clamp(level_of_detail(), 0.0, max_level);
        rgb *= textureLod(base_color, v_uv, lod).rgb;
    }
    colour = vec4(rgb, 1.0);
}
