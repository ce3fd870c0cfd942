#version 330 core
// A protocol view of the normalised mesh (PROTOCOL.md): clip = pan * projection * view * p.

uniform mat4 clip_from_world;

in vec3 position;  // normalised scene units
in vec2 uv;        // OpenGL convention: v = 0 is the bottom row of the texture image

out vec2 v_uv;                 // perspective-correct UV
noperspective out vec3 v_uvw;  // (u, v, 1) / w_clip: affine in screen space

void main() {
    gl_Position = clip_from_world * vec4(position, 1.0);
    v_uv = uv;
    v_uvw = vec3(uv, 1.0) / gl_Position.w;
}
