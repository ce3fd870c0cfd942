#version 330 core

uniform vec4 line_colour;
out vec4 colour;

void main() {
    colour = line_colour;
}
