// FXAA (Lottes 2009, the compact "FXAA 2" variant): edges found from the luma of the 4
// diagonal neighbours, then blended along the edge with 2 or 4 filtered samples. Runs on
// the sRGB-encoded colour (perceptual luma), after a single-sample render: screen-space
// work, where MSAA multiplies the whole rasterization on a software GL. Defines:
// MARK_EDGES (the first of the two passes, see below).

uniform sampler2D u_scene;   // single-sample colour, LINEAR filtering, clamped
uniform vec2 u_texel;        // 1 / size

layout(location = 0) out vec4 f_color;

const float EDGE_MIN = 1.0 / 24.0;   // contrast below this (dark areas) is no edge
const float EDGE_REL = 1.0 / 8.0;    // nor is contrast below this fraction of the local max
const float REDUCE_MUL = 1.0 / 8.0;
const float REDUCE_MIN = 1.0 / 128.0;
const float SPAN_MAX = 8.0;

float luma(vec3 c) { return dot(c, vec3(0.299, 0.587, 0.114)); }

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    ivec2 hi = textureSize(u_scene, 0) - 1;
    vec3 rgb_m = texelFetch(u_scene, p, 0).rgb;
    float nw = luma(texelFetch(u_scene, clamp(p + ivec2(-1, -1), ivec2(0), hi), 0).rgb);
    float ne = luma(texelFetch(u_scene, clamp(p + ivec2(1, -1), ivec2(0), hi), 0).rgb);
    float sw = luma(texelFetch(u_scene, clamp(p + ivec2(-1, 1), ivec2(0), hi), 0).rgb);
    float se = luma(texelFetch(u_scene, clamp(p + ivec2(1, 1), ivec2(0), hi), 0).rgb);
    float m = luma(rgb_m);
    float lo = min(m, min(min(nw, ne), min(sw, se)));
    float up = max(m, max(max(nw, ne), max(sw, se)));
    bool flat_area = up - lo < max(EDGE_MIN, up * EDGE_REL);  // most pixels
#ifdef MARK_EDGES
    // Pass 1 writes no colour (masked off: the image was copied already): the depth
    // marks the edges (1) for pass 2, drawn at depth 0.5, which the early depth test then
    // skips everywhere else. (A software GL runs both sides of a branch, so one pass would
    // blend every pixel.)
    gl_FragDepth = flat_area ? 0.0 : 1.0;
#else
    if (flat_area) {
        f_color = vec4(rgb_m, 1.0);
        return;
    }
    vec2 dir = vec2(-((nw + ne) - (sw + se)), (nw + sw) - (ne + se));
    float reduce = max((nw + ne + sw + se) * (0.25 * REDUCE_MUL), REDUCE_MIN);
    dir = clamp(dir / (min(abs(dir.x), abs(dir.y)) + reduce), -SPAN_MAX, SPAN_MAX) * u_texel;
    vec2 uv = gl_FragCoord.xy * u_texel;
    vec3 a = 0.5 * (texture(u_scene, uv - dir / 6.0).rgb + texture(u_scene, uv + dir / 6.0).rgb);
    vec3 b = 0.5 * a + 0.25 * (texture(u_scene, uv - 0.5 * dir).rgb + texture(u_scene, uv + 0.5 * dir).rgb);
    float lb = luma(b);
    f_color = vec4((lb < lo || lb > up) ? a : b, 1.0);
#endif
}
