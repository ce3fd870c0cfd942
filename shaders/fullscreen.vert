#version 330 core
// One triangle that covers the viewport; no vertex buffer needed.

out vec2 v_pos;  // [0, 1]^2 over the viewport, y up

void main() {
    vec2 corner = vec2((gl_VertexID << 1) & 2, gl_VertexID & 2);
    v_pos = corner;
    gl_Position = vec4(corner * 2.0 - 1.0, 0.0, 1.0);
}
