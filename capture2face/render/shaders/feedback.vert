// Transform-feedback pass: the deformed positions in head coordinates, read back by
// Renderer.deformed_positions (tests compare them with the CPU reference).
#include "deform.glsl"

out vec3 tf_position;

void main() {
    vec3 normal;
    deform_vertex(tf_position, normal);
}
