// Shading pass, fragment stage: wrinkle maps over the base normal map (per-pixel weights
// from the driver), skin lighting, filmic tone mapping, sRGB output.
// Defines: FACE_SKIN (1: the face skin, material 0, with its normal and wrinkle maps;
// 0: every other material, drawn apart: llvmpipe runs every side of a branch, so leaving
// the maps out of their program makes their pixels ~25% cheaper),
// N_MAPS (wrinkle maps, <= 4), SHADE_WRINKLES (0: weights only feed the
// influence output), BLEND_PD | BLEND_OAT, DRIVER_*, VIEW_SHADED | VIEW_INFLUENCE,
// INFLUENCE_OUTPUT (shaded view: the influence view also goes to colour attachment 1),
// ALPHA_MASK | ALPHA_BLEND (glTF's alpha modes: discard below the cutoff | blend by the
// base colour's alpha; neither: opaque).
#include "normal_blend.glsl"
#include "color.glsl"

uniform sampler2D u_albedo;        // sRGB texture, decoded to linear by the sampler
uniform sampler2D u_normal_map;
#if !defined(DRIVER_OFF) && N_MAPS > 0 && SHADE_WRINKLES
#define WRINKLES 1
// Jimenez's partial derivatives, decoded at upload: layer j holds map 2j in RG and map
// 2j + 1 in BA, so two maps cost one fetch.
uniform sampler2DArray u_wrinkle_pd;
#endif
#ifdef DRIVER_ZONES
uniform sampler2D u_zone_mask0;    // zones 0-3 in RGBA
uniform sampler2D u_zone_mask1;    // zones 4-7
uniform vec4 u_zone_weight[2];     // 8 zone weights in [-1, 1]
uniform vec4 u_stretch_slot;
uniform vec4 u_compress_slot;
#endif

uniform vec3 u_light_direction;    // camera space, unit, towards the key light
uniform vec3 u_light_color;
uniform vec3 u_fill_color;         // second light from the mirrored side
uniform vec3 u_fill_direction;     // camera space, unit: the key light mirrored across the view axis
uniform vec3 u_ambient;
uniform vec3 u_map_color[4];       // influence view: colour of each wrinkle map

in vec3 v_position;
in vec3 v_normal;
in vec4 v_tangent;
in vec2 v_uv;
in vec4 v_map_weight;
flat in int v_material;
#ifdef ALPHA_MASK
flat in float v_alpha_cutoff;
#endif

layout(location = 0) out vec4 f_color;
#if defined(INFLUENCE_OUTPUT) && !defined(VIEW_INFLUENCE)
layout(location = 1) out vec4 f_influence;
#endif

const float PI = 3.14159265;

vec4 map_weights() {
#ifdef DRIVER_ZONES
    // Oat: dot the mask vector with the weight vector; +1 compress map, -1 stretch map.
    // Frames without zone weights skip the two mask fetches.
    if (all(equal(u_zone_weight[0], vec4(0.0))) && all(equal(u_zone_weight[1], vec4(0.0))))
        return vec4(0.0);
    float s = dot(texture(u_zone_mask0, v_uv), u_zone_weight[0]) + dot(texture(u_zone_mask1, v_uv), u_zone_weight[1]);
    s = clamp(s, -1.0, 1.0);
    return max(-s, 0.0) * u_stretch_slot + max(s, 0.0) * u_compress_slot;
#else
    return clamp(v_map_weight, 0.0, 1.0);
#endif
}

#ifdef WRINKLES
// Partial derivatives of maps (2 layer, 2 layer + 1), fetched only where either weighs.
vec4 wrinkle_pd(int layer, vec2 w) {
    return any(greaterThan(w, vec2(0.0))) ? texture(u_wrinkle_pd, vec3(v_uv, layer)) : vec4(0.0);
}
#endif

// Tangent-space normal: base map with the weighted wrinkle maps blended on top.
vec3 tangent_normal(vec4 w) {
    vec3 base = unpack_normal(texture(u_normal_map, v_uv).rgb);
#ifdef BLEND_OAT
    // Oat's detail blend needs the wrinkle normals: n = normalize(dx, dy, 1) from the
    // derivatives is exact for unit normals with z > 0.
    vec3 wrinkle = vec3(0.0, 0.0, 1.0);
#ifdef WRINKLES
    const vec3 Z = vec3(0.0, 0.0, 1.0);
    if (any(greaterThan(w, vec4(0.0)))) {
        vec4 d = wrinkle_pd(0, w.xy);
        wrinkle += w.x * (pd_decode(d.rg) - Z) + w.y * (pd_decode(d.ba) - Z);
#if N_MAPS > 2
        d = wrinkle_pd(1, w.zw);
        wrinkle += w.z * (pd_decode(d.rg) - Z) + w.w * (pd_decode(d.ba) - Z);
#endif
    }
#endif
    return oat_blend(normalize(wrinkle), base);
#else
    // Jimenez: blending is a weighted sum of derivatives.
    vec2 d = pd_encode(base);
#ifdef WRINKLES
    vec4 d01 = wrinkle_pd(0, w.xy);
    d += w.x * d01.rg + w.y * d01.ba;
#if N_MAPS > 2
    vec4 d23 = wrinkle_pd(1, w.zw);
    d += w.z * d23.rg + w.w * d23.ba;
#endif
#endif
    return pd_decode(d);
#endif
}

// Influence view: each wrinkle map's weight painted in its colour over a grey shading.
vec4 influence_color(vec3 ng, vec3 l, vec4 w) {
    vec3 grey = vec3(0.5) * (0.35 + 0.65 * max(dot(ng, l), 0.0));
    float total = min(w.x + w.y + w.z + w.w, 1.0);
    vec3 heat = w.x * u_map_color[0] + w.y * u_map_color[1] + w.z * u_map_color[2] + w.w * u_map_color[3];
    return vec4(grey * (1.0 - total) + heat, 1.0);
}

float beckmann(float ndoth, float m) {
    float c2 = ndoth * ndoth;
    float m2 = m * m;
    return exp((c2 - 1.0) / (m2 * c2)) / (PI * m2 * c2 * c2);
}

// Kelemen / Szirmay-Kalos specular with a Beckmann lobe and Schlick Fresnel (d'Eon & Luebke).
float ksk_specular(vec3 n, vec3 l, vec3 v, float m, float rho_s) {
    float ndotl = dot(n, l);
    if (ndotl <= 0.0) return 0.0;
    vec3 h = l + v;
    vec3 hn = normalize(h);
    float ndoth = max(dot(n, hn), 1e-4);
    float f = 1.0 - max(dot(hn, v), 0.0);
    float f2 = f * f;
    float fresnel = 0.028 + 0.972 * (f2 * f2 * f);  // f^5: llvmpipe's pow is exp2(5 log2 f)
    return ndotl * rho_s * max(beckmann(ndoth, m) * fresnel / dot(h, h), 0.0);
}

// Wrapped diffuse, wider in red: a cheap stand-in for subsurface scattering.
vec3 skin_diffuse(float ndotl) {
    const vec3 wrap = vec3(0.40, 0.18, 0.12);
    return max((vec3(ndotl) + wrap) / (1.0 + wrap), 0.0);
}

// The base colour's alpha where the material reads it (MASK, BLEND), else 1.
float base_alpha() {
#if defined(ALPHA_MASK) || defined(ALPHA_BLEND)
    float alpha = texture(u_albedo, v_uv).a;
#ifdef ALPHA_MASK
#ifdef MIP_SCALE
    // Mip levels average thin cards' (lashes') alpha below the cutoff: scale it up by
    // the level sampled (Castano's coverage-preserving idea, as a per-pixel scale).
    vec2 texel = v_uv * vec2(textureSize(u_albedo, 0));
    vec2 dx = dFdx(texel), dy = dFdy(texel);
    alpha *= 1.0 + MIP_SCALE * max(0.5 * log2(max(dot(dx, dx), dot(dy, dy))), 0.0);
#endif
    if (alpha < v_alpha_cutoff) discard;
    return 1.0;
#else
    return alpha;
#endif
#else
    return 1.0;
#endif
}

void main() {
    float alpha = base_alpha();
    vec3 ng = normalize(v_normal);
    vec3 l = u_light_direction;
    vec3 lf = u_fill_direction;
    vec3 v = normalize(-v_position);
#if FACE_SKIN
    vec4 w = map_weights();
#else
    vec4 w = vec4(0.0);  // no wrinkles beyond the face skin
#endif

#ifdef VIEW_INFLUENCE
    f_color = vec4(influence_color(ng, l, w).rgb, alpha);
#else
#ifdef INFLUENCE_OUTPUT
    f_influence = vec4(influence_color(ng, l, w).rgb, alpha);
#endif
    vec3 n = ng;
#if FACE_SKIN  // the head beyond the face (4) has a flat normal map
    vec3 t = normalize(v_tangent.xyz - ng * dot(ng, v_tangent.xyz));
    vec3 b = v_tangent.w * cross(ng, t);
    vec3 tn = tangent_normal(w);
    n = normalize(t * tn.x + b * tn.y + ng * tn.z);
#endif
    vec3 albedo = texture(u_albedo, v_uv).rgb;
    float ndotl = dot(n, l);
    // One lighting path for every material (a software GL runs every side of a branch):
    // skin wraps its diffuse; eyes are glossy; the mouth interior dark and matte;
    // Teeth and tongue (3) sit inside the mouth: half lit (no shadows here), a little gloss.
    bool skin = v_material == 0 || v_material == 4, eye = v_material == 1, teeth = v_material == 3;
    vec3 diffuse = skin ? skin_diffuse(ndotl) : vec3(max(ndotl, 0.0));
    float specular = ksk_specular(n, l, v, eye ? 0.08 : 0.3, eye ? 1.2 : (skin ? 0.18 : (teeth ? 0.06 : 0.018)));
    if (v_material == 2) albedo *= 0.25;
    if (teeth) albedo *= 0.55;
    float hemi = 0.6 + 0.4 * n.y;
    vec3 radiance = albedo * (u_light_color * diffuse + u_fill_color * max(dot(n, lf), 0.0) + u_ambient * hemi)
                  + u_light_color * specular;
    f_color = vec4(linear_to_srgb(aces_film(radiance)), alpha);
#endif
}
