// Stage III's deferred shading (paper eq. 9-10, method-notes §3.5):
//   I = (1 - R) I_scat + R F(F0, cos) Phi(x_refl, w_r),
// with Phi the light-field MLP evaluated only at the pixels whose R exceeds
// a threshold (compacted into a sample list). The other pixels show no
// reflection: I = I_scat there, with no gradient to R or F0 (an error of
// R |F Phi - I_scat| <= threshold), F Schlick's
// F0 + (1 - F0)(1 - cos)^5 (or F0 alone with Schlick off), F0 = F0 sum /
// max(alpha_R, F0_EPS), and R = sum w r unnormalized.
//
// The reflection render has 4 feature channels [F0 sum (3), R] (the
// sigmoid of the material, rasterized), then alpha, depth (sum w z),
// normal (3, view space, unnormalized), median, distortion.
//
// x_refl is the expected surface point (depth / alpha along the pixel's
// ray) in world space, normalized as (x - centre) * scale; w_r is the view
// ray mirrored about the normalized blended normal, in world space.
#ifndef TGS_LIGHTFIELD_COMMON_GLSL
#define TGS_LIGHTFIELD_COMMON_GLSL
#include "common.glsl"

layout(push_constant) uniform Push {
    uint width;
    uint height;
    float threshold;  // evaluate Phi where R > threshold
    uint schlick;     // 1: F = Schlick(F0, cos); 0: F = F0
    float fx, fy, cx, cy;
    vec4 rot[3];      // world_to_view rows: xyz = R row, w = t
    vec4 centre;      // xyz: centre of the normalization box
    vec4 scale;       // xyz: 1 / half extent
    uint max_samples; // the sample list's capacity (compact writes no more)
    float r_prior;    // composite backward: added to dL/dR at every pixel
    uint pad1, pad2;
} pc;

const uint CH = 4u;
const uint NONE = 0xffffffffu;
const float F0_EPS = 1e-6;
const float NORMAL_EPS = 1e-12;

layout(std430, binding = 0) readonly buffer Refl { float refl[]; };

uint npix() {
    return pc.width * pc.height;
}
float refl_plane(uint plane, uint pix) {
    return refl[plane * npix() + pix];
}
float refl_r(uint pix) {
    return refl_plane(3u, pix);
}
bool evaluated(uint pix) {
    return refl_r(pix) > pc.threshold;
}
// The pixel's ray in view space (z = 1).
vec3 pixel_ray(uint pix) {
    float x = float(pix % pc.width), y = float(pix / pc.width);
    return vec3((x - pc.cx) / pc.fx, (y - pc.cy) / pc.fy, 1.0);
}
vec3 blended_normal(uint pix) {
    return vec3(refl_plane(CH + 2u, pix), refl_plane(CH + 3u, pix), refl_plane(CH + 4u, pix));
}
// R^T v (view to world, a direction).
vec3 to_world_dir(vec3 v) {
    return pc.rot[0].xyz * v.x + pc.rot[1].xyz * v.y + pc.rot[2].xyz * v.z;
}

// Schlick's factor at a pixel.
struct Fresnel {
    float ae;    // max(alpha_R, F0_EPS)
    vec3 F0s;    // sum w f0
    float m;     // (1 - clamp(cos, 0, 1))^5 (0 with Schlick off)
    vec3 F;      // F0 + (1 - F0) m
};

Fresnel fresnel_terms(uint pix) {
    Fresnel f;
    f.ae = max(refl_plane(CH, pix), F0_EPS);
    f.F0s = vec3(refl_plane(0u, pix), refl_plane(1u, pix), refl_plane(2u, pix));
    vec3 F0 = f.F0s / f.ae;
    f.m = 0.0;
    if (pc.schlick != 0u) {
        vec3 N = blended_normal(pix);
        float len = length(N);
        vec3 v = -normalize(pixel_ray(pix));
        float c = len > NORMAL_EPS ? dot(N / len, v) : 1.0;
        f.m = pow(1.0 - clamp(c, 0.0, 1.0), 5.0);
    }
    f.F = F0 + (1.0 - F0) * f.m;
    return f;
}

#endif
