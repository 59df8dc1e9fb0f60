// Output colour: filmic tone mapping and the sRGB encoding.

vec3 aces_film(vec3 x) {  // Narkowicz's fit of the ACES filmic curve
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

// The sRGB encoding, its 1.055 c^(1/2.4) - 0.055 fitted by three square roots (within
// 0.25 / 255): cheaper than pow, which llvmpipe evaluates as exp2(log2(c) / 2.4).
vec3 linear_to_srgb(vec3 c) {
    vec3 s1 = sqrt(c), s2 = sqrt(s1), s3 = sqrt(s2);
    return mix(12.92 * c, 0.662002687 * s1 + 0.684122060 * s2 - 0.323583601 * s3 - 0.0225411470 * c, step(0.0031308, c));
}
