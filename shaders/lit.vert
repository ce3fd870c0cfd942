#version 330 core
// A protocol view of the normalised mesh with what lit shading needs (PROTOCOL.md, protocol 2):
// position, vertex normal, tangent (xyz, handedness w) and UV, interpolated perspective-correctly.

uniform mat4 clip_from_world;

in vec3 position;  // normalised scene units
in vec3 normal;
in vec4 tangent;
in vec2 uv;        // OpenGL convention: v = 0 is the bottom row of the texture image

out vec3 v_position;
out vec3 v_normal;
out vec4 v_tangent;
out vec2 v_uv;
noperspective out vec3 v_uvw;  // (u, v, 1) / w_clip: affine in screen space

void main() {
    gl_Position = clip_from_world * vec4(position, 1.0);
    v_position = position;
    v_normal = normal;
    v_tangent = tangent;
    v_uv = uv;
    v_uvw = vec3(uv, 1.0) / gl_Position.w;
}
