#version 330 core
// A protocol view of the normalised mesh (PROTOCOL.md): clip = pan * projection * view * p.
// VIEWS (1 or 2, defined by the app) surfaces are drawn in one pass, each with its own UVs.

uniform mat4 clip_from_world;

in vec3 position;  // normalised scene units
in vec2 uv;        // OpenGL convention: v = 0 is the bottom row of the texture image
#if VIEWS == 2
in vec2 uv_b;      // the second surface's UVs
#endif

out vec2 v_uv[VIEWS];                 // perspective-correct UV
noperspective out vec3 v_uvw[VIEWS];  // (u, v, 1) / w_clip: affine in screen space

void main() {
    gl_Position = clip_from_world * vec4(position, 1.0);
    v_uv[0] = uv;
#if VIEWS == 2
    v_uv[1] = uv_b;
#endif
    for (int i = 0; i < VIEWS; ++i)
        v_uvw[i] = vec3(v_uv[i], 1.0) / gl_Position.w;
}
