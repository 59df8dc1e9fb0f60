// Shading pass, vertex stage: the mesh comes deformed (NumPy, per frame), so this stage
// only applies the head pose and the projection. Defines: DRIVER_AUTO | DRIVER_ZONES |
// DRIVER_DYNAMIC | DRIVER_OFF; ALPHA_MASK (the per-vertex alpha cutoff).

uniform mat4 u_model_view;     // head -> camera (cm)
uniform mat3 u_normal_matrix;  // inverse transpose of its upper 3x3
uniform mat4 u_projection;

in vec3 in_position;           // deformed, head coordinates (cm)
in vec3 in_normal;             // deformed, unit
#if defined(DRIVER_AUTO) || defined(DRIVER_DYNAMIC)
in vec4 in_map_weight;         // per-vertex wrinkle-map weights (maps 0..3) of the driver
#endif
in vec4 in_tangent;
in vec2 in_uv;
in float in_material;
#ifdef ALPHA_MASK
in float in_alpha_cutoff;      // the material's alphaCutoff
flat out float v_alpha_cutoff;
#endif

out vec3 v_position;   // camera space
out vec3 v_normal;
out vec4 v_tangent;
out vec2 v_uv;
out vec4 v_map_weight;
flat out int v_material;

void main() {
    vec4 cam = u_model_view * vec4(in_position, 1.0);
    v_position = cam.xyz;
    v_normal = u_normal_matrix * in_normal;
    v_tangent = vec4(mat3(u_model_view) * in_tangent.xyz, in_tangent.w);
    v_uv = in_uv;
    v_material = int(in_material + 0.5);
#ifdef ALPHA_MASK
    v_alpha_cutoff = in_alpha_cutoff;
#endif
#if defined(DRIVER_AUTO) || defined(DRIVER_DYNAMIC)
    v_map_weight = in_map_weight;
#else
    v_map_weight = vec4(0.0);
#endif
    gl_Position = u_projection * cam;
}
