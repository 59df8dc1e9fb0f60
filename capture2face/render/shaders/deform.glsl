// Deformation shared by the shading pass and the transform-feedback pass:
// morph targets (Yang: deltas in float textures, weights as uniforms), then linear blend
// skinning with translation-only bones (Dutreve). Defines: N_VERTICES, N_BONES,
// MAX_MORPHS (>= 1), MORPH_TEX_WIDTH.

uniform sampler2D u_morph_positions;  // RGB32F, texel m * N_VERTICES + vertex, row-major
uniform sampler2D u_morph_normals;
uniform int u_morph_count;            // morphs with a non-zero weight this frame
uniform int u_morph_index[MAX_MORPHS];
uniform float u_morph_weight[MAX_MORPHS];
uniform vec3 u_bone_offset[N_BONES];  // bone position - rest position, head coordinates

in vec3 in_position;
in vec3 in_normal;
in ivec4 in_joints;
in vec4 in_weights;

void deform_vertex(out vec3 position, out vec3 normal) {
    vec3 p = in_position;
    vec3 n = in_normal;
    // Only the active morphs are visited: a frame typically uses a few of them.
    for (int k = 0; k < u_morph_count; ++k) {
        int texel = u_morph_index[k] * N_VERTICES + gl_VertexID;
        ivec2 st = ivec2(texel % MORPH_TEX_WIDTH, texel / MORPH_TEX_WIDTH);
        p += u_morph_weight[k] * texelFetch(u_morph_positions, st, 0).xyz;
        n += u_morph_weight[k] * texelFetch(u_morph_normals, st, 0).xyz;
    }
    position = p + in_weights.x * u_bone_offset[in_joints.x] + in_weights.y * u_bone_offset[in_joints.y]
                 + in_weights.z * u_bone_offset[in_joints.z] + in_weights.w * u_bone_offset[in_joints.w];
    // Translations leave normals unchanged; only the morphs bend them.
    normal = normalize(n);
}
