// Deferred shading of the two sets (paper eq. 6, 9; method-notes §3.2):
//   I = (1 - R) I_scat + R I_refl,
//   I_refl = A                      (Schlick off: A = sum w f0 E(w_i))
//   I_refl = F(F0, cos) * A         (Schlick on:  A = sum w E(w_i)),
//   F = F0 + (1 - F0) (1 - cos)^5,  F0 = sum w f0 / max(alpha_R, EPS),
//   cos = clamp(n.v, 0, 1) with n the normalized blended normal of the
//   reflection set and v the unit direction from the pixel to the camera.
// R = sum w r is unnormalized (fades at coverage edges). The scattering
// render's colour has its background blended in; the reflection render's
// background is 0.
//
// Planes (width * height floats each): the scattering render's first 3;
// the reflection render's CH features [A (3), R, F0 sum (3) if CH = 7],
// alpha, depth, normal (3), median, distortion. The loss input has the
// layout of a 3-channel render: the composite, then the reflection set's
// alpha..distortion (so the image loss also computes its normal
// consistency).
#ifndef TGS_COMPOSITE_COMMON_GLSL
#define TGS_COMPOSITE_COMMON_GLSL
#include "common.glsl"

layout(push_constant) uniform Push {
    uint width;
    uint height;
    uint channels;   // reflection render's feature channels (4 or 7)
    uint schlick;    // 1: Schlick Fresnel with the blended F0 (needs CH = 7)
    float fx, fy, cx, cy;
    uint scat_grad;  // backward: 1 also writes dL/dI_scat
    float r_prior;   // backward: added to dL/dR at every pixel
    float alpha_prior; // backward: added to dL/dalpha at every pixel
    float mask_weight; // backward: (alpha - mask) times this added to dL/dalpha
} pc;

const float F0_EPS = 1e-6;
const float NORMAL_EPS = 1e-12;

uint npix() {
    return pc.width * pc.height;
}

// Unit direction from the pixel's surface point to the camera (view space;
// pixel centres at integer coordinates as in the rasterizer).
vec3 pixel_view_dir(uint pix) {
    float x = float(pix % pc.width), y = float(pix / pc.width);
    return -normalize(vec3((x - pc.cx) / pc.fx, (y - pc.cy) / pc.fy, 1.0));
}

layout(std430, binding = 0) readonly buffer Scat { float scat[]; };
layout(std430, binding = 1) readonly buffer Refl { float refl[]; };

vec3 scat_colour(uint pix) {
    uint n = npix();
    return vec3(scat[pix], scat[n + pix], scat[2u * n + pix]);
}
// The blended reflection colour A and reflectivity R.
vec3 refl_colour(uint pix) {
    uint n = npix();
    return vec3(refl[pix], refl[n + pix], refl[2u * n + pix]);
}
float refl_r(uint pix) {
    return refl[3u * npix() + pix];
}

// Schlick's terms at a pixel (CH = 7).
struct Schlick {
    float alpha;  // alpha_R
    float ae;     // max(alpha_R, F0_EPS)
    vec3 F0s;     // sum w f0
    vec3 F0;      // F0s / ae
    vec3 N;       // blended normal (unnormalized)
    float len;    // |N|
    vec3 v;       // unit direction to the camera
    float craw;   // n.v before the clamp (1 without a normal)
    float m;      // (1 - clamp(craw, 0, 1))^5
    vec3 F;       // F0 + (1 - F0) m
};

Schlick schlick_terms(uint pix) {
    uint n = npix(), ch = pc.channels;
    Schlick s;
    s.alpha = refl[ch * n + pix];
    s.ae = max(s.alpha, F0_EPS);
    s.F0s = vec3(refl[4u * n + pix], refl[5u * n + pix], refl[6u * n + pix]);
    s.F0 = s.F0s / s.ae;
    s.N = vec3(refl[(ch + 2u) * n + pix], refl[(ch + 3u) * n + pix], refl[(ch + 4u) * n + pix]);
    s.len = length(s.N);
    s.v = pixel_view_dir(pix);
    s.craw = s.len > NORMAL_EPS ? dot(s.N / s.len, s.v) : 1.0;
    s.m = pow(1.0 - clamp(s.craw, 0.0, 1.0), 5.0);
    s.F = s.F0 + (1.0 - s.F0) * s.m;
    return s;
}

#endif
