// Tangent-space normal blending: Jimenez's partial derivatives and Oat's detail blend.

vec3 unpack_normal(vec3 rgb) {  // texture value of n * 127.5 + 127.5 -> unit normal
    return normalize(rgb * 2.0 - 1.0);
}

// Partial-derivative normals (Jimenez 2011, without Acton's sign): n' = (nx/nz, ny/nz).
vec2 pd_encode(vec3 n) {
    return n.xy / max(n.z, 1e-3);
}

vec3 pd_decode(vec2 d) {
    return normalize(vec3(d, 1.0));
}

// Oat 2007 / Dutreve 5.3: wrinkle normal W over base normal N.
vec3 oat_blend(vec3 w, vec3 n) {
    return normalize(vec3(w.xy + n.xy, w.z * n.z));
}
