#version 460
// Stage III composite, backward (lightfield/common.glsl): from the loss
// gradient's colour planes g, at an evaluated pixel, to
//   dPhi (per sample, its only writer)      = g R F,
//   the reflection render's planes: dR      = sum_c g (F Phi - S),
//                                   dF0 sum = g R Phi (1 - m) / ae,
//     and 0 for alpha..distortion (the reflection geometry is frozen),
//   and, when scat_grad is set, dI_scat     = g (1 - R);
// at the other pixels (I = I_scat) dI_scat = g and the rest 0; pc.r_prior
// is added to dR at every pixel (a penalty on the mean of R).
#include "lightfield/common.glsl"

layout(std430, binding = 1) readonly buffer Scat { float scat[]; };
layout(std430, binding = 2) readonly buffer SampleOf { uint sample_of[]; };
layout(std430, binding = 3) readonly buffer Phi { float phi[]; };
layout(std430, binding = 4) readonly buffer LossGrad { float lg[]; };
layout(std430, binding = 5) writeonly buffer DPhi { float dphi[]; };
layout(std430, binding = 6) writeonly buffer ReflGrad { float rg[]; };
layout(std430, binding = 7) writeonly buffer ScatGrad { float sg[]; };
layout(constant_id = 3) const uint SCAT_GRAD = 0;

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = npix();
    if (pix >= n) {
        return;
    }
    uint s = sample_of[pix];
    vec3 S = vec3(scat[pix], scat[n + pix], scat[2u * n + pix]);
    vec3 g = vec3(lg[pix], lg[n + pix], lg[2u * n + pix]);
    float R = 0.0;
    vec3 dF0s = vec3(0.0);
    float dR = 0.0;
    if (s != NONE) {
        R = refl_r(pix);
        vec3 P = vec3(phi[3u * s], phi[3u * s + 1u], phi[3u * s + 2u]);
        Fresnel f = fresnel_terms(pix);
        vec3 d = g * R * f.F;
        dphi[3u * s] = d.x;
        dphi[3u * s + 1u] = d.y;
        dphi[3u * s + 2u] = d.z;
        dF0s = g * R * P * (1.0 - f.m) / f.ae;
        dR = dot(g, f.F * P - S);
    }
    rg[pix] = dF0s.x;
    rg[n + pix] = dF0s.y;
    rg[2u * n + pix] = dF0s.z;
    rg[3u * n + pix] = dR + pc.r_prior;
    for (uint k = 0u; k < 7u; k++) {
        rg[(CH + k) * n + pix] = 0.0;
    }
    if (SCAT_GRAD != 0u) {
        vec3 ds = g * (1.0 - R);
        sg[pix] = ds.x;
        sg[n + pix] = ds.y;
        sg[2u * n + pix] = ds.z;
    }
}
