// Shading pass, vertex stage: deform, carry the per-vertex wrinkle-map weights of the
// chosen driver, then head pose and projection. Defines: DRIVER_AUTO | DRIVER_ZONES |
// DRIVER_DYNAMIC | DRIVER_OFF, plus those of deform.glsl.
#include "deform.glsl"

uniform mat4 u_model_view;     // head -> camera (cm)
uniform mat3 u_normal_matrix;  // inverse transpose of its upper 3x3
uniform mat4 u_projection;

in vec4 in_tangent;
in vec2 in_uv;
in float in_material;

#ifdef DRIVER_AUTO
// Dutreve 5.2: per-bone reference-pose influences already summed per wrinkle map
// (x, y, z, w = maps 0..3); Inf(v, P_k) = sum_i w_vi * I_Pk(J_i).
uniform vec4 u_bone_map_weight[N_BONES];
#endif
#ifdef DRIVER_DYNAMIC
// Oat: smoothed area-change weight per vertex, + compress / - stretch.
in float in_dynamic;
uniform vec4 u_stretch_slot;   // one-hot: which map is "stretch"
uniform vec4 u_compress_slot;
#endif

out vec3 v_position;   // camera space
out vec3 v_normal;
out vec4 v_tangent;
out vec2 v_uv;
out vec4 v_map_weight;
flat out int v_material;

void main() {
    vec3 position, normal;
    deform_vertex(position, normal);
    vec4 cam = u_model_view * vec4(position, 1.0);
    v_position = cam.xyz;
    v_normal = u_normal_matrix * normal;
    v_tangent = vec4(mat3(u_model_view) * in_tangent.xyz, in_tangent.w);
    v_uv = in_uv;
    v_material = int(in_material + 0.5);
#if defined(DRIVER_AUTO)
    v_map_weight = in_weights.x * u_bone_map_weight[in_joints.x] + in_weights.y * u_bone_map_weight[in_joints.y]
                 + in_weights.z * u_bone_map_weight[in_joints.z] + in_weights.w * u_bone_map_weight[in_joints.w];
#elif defined(DRIVER_DYNAMIC)
    v_map_weight = max(-in_dynamic, 0.0) * u_stretch_slot + max(in_dynamic, 0.0) * u_compress_slot;
#else
    v_map_weight = vec4(0.0);
#endif
    gl_Position = u_projection * cam;
}
