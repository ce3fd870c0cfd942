#version 330 core
// Line segments given in UV coordinates, drawn over the [0, 1]^2 texture square.

in vec2 uv;

void main() {
    gl_Position = vec4(uv * 2.0 - 1.0, 0.0, 1.0);
}
