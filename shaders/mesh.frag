#version 450 core
// The PROTOCOL.md sampler, the GLSL twin of geoscaler/texture.py.
// The texture is GL_SRGB8_ALPHA8 with a mip chain built like texture.py's (2 x 2 box averages in
// linear light), so every fetch is decoded to linear light by the hardware before filtering.
// Trilinear filtering, repeat addressing; the level of detail is log2 of the larger singular
// value of the screen-space UV Jacobian in texels, with the Jacobian taken exactly: u/w, v/w and
// 1/w are affine across a triangle, so their finite differences are exact derivatives.
// VIEWS (1 or 2, defined by the app) surfaces are drawn in one pass, surface i into colour[i].

uniform sampler2D base_color[VIEWS];
uniform bool textured[VIEWS];
uniform vec3 base_color_factor;  // linear RGB
uniform float max_level[VIEWS];  // mip levels - 1

in vec2 v_uv[VIEWS];
noperspective in vec3 v_uvw[VIEWS];

layout(location = 0) out vec4 colour[VIEWS];  // linear RGB, alpha 1 marks coverage

float level_of_detail(vec3 uvw, vec2 size) {
    vec3 ddx = dFdxFine(uvw);
    vec3 ddy = dFdyFine(uvw);
    vec2 uv = uvw.xy / uvw.z;
    vec2 dx = (ddx.xy - uv * ddx.z) / uvw.z * size;  // d(u, v)/dx in texels
    vec2 dy = (ddy.xy - uv * ddy.z) / uvw.z * size;
    float frobenius = dot(dx, dx) + dot(dy, dy);
    float det = dx.x * dy.y - dy.x * dx.y;
    float gap = sqrt(max(frobenius * frobenius - 4.0 * det * det, 1e-20));
    return 0.5 * log2(max(0.5 * (frobenius + gap), 1e-30));
}

void main() {
    for (int i = 0; i < VIEWS; ++i) {
        vec3 rgb = base_color_factor;
        if (textured[i]) {
            vec2 size = vec2(textureSize(base_color[i], 0));
            float lod = clamp(level_of_detail(v_uvw[i], size), 0.0, max_level[i]);
            rgb *= textureLod(base_color[i], v_uv[i], lod).rgb;
        }
        colour[i] = vec4(rgb, 1.0);
    }
}
