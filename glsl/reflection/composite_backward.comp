#version 460
// Deferred composite, backward: from the loss gradient of the loss input
// (composite colour + the reflection set's alpha..distortion planes) to the
// reflection render's planes (all written) and, with scat_grad, to the
// scattering render's colour. pc.r_prior is added to dL/dR and
// pc.alpha_prior to dL/dalpha everywhere (penalties on the means of R and of
// the reflection set's alpha, the area it covers); with pc.mask_weight != 0
// also (alpha - mask) pc.mask_weight, the gradient of
// mask_weight / 2 sum (alpha - mask)^2 (the set drawn to a glass mask).
#include "reflection/composite_common.glsl"

layout(std430, binding = 2) readonly buffer LossGrad { float g_in[]; };
layout(std430, binding = 3) writeonly buffer ReflGrad { float g_refl[]; };
layout(std430, binding = 4) buffer ScatGrad { float g_scat[]; };
layout(std430, binding = 5) readonly buffer Mask { float mask[]; };

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = npix();
    if (pix >= n) {
        return;
    }
    uint ch = pc.channels;
    float R = refl_r(pix);
    vec3 A = refl_colour(pix);
    vec3 S = scat_colour(pix);
    vec3 dI = vec3(g_in[pix], g_in[n + pix], g_in[2u * n + pix]);
    float d_alpha = g_in[3u * n + pix];
    vec3 dN = vec3(g_in[5u * n + pix], g_in[6u * n + pix], g_in[7u * n + pix]);
    vec3 dA, dF0s = vec3(0.0);
    float dR;
    if (pc.schlick != 0u) {
        Schlick s = schlick_terms(pix);
        vec3 F = s.F;
        dA = R * F * dI;
        dR = dot(dI, F * A - S);
        vec3 dF = R * A * dI;
        vec3 dF0 = dF * (1.0 - s.m);
        dF0s = dF0 / s.ae;
        if (s.alpha > F0_EPS) {
            d_alpha -= dot(dF0, s.F0s) / (s.alpha * s.alpha);
        }
        float dm = dot(dF, 1.0 - s.F0);
        if (s.len > NORMAL_EPS && s.craw > 0.0 && s.craw < 1.0) {
            float dc = -5.0 * pow(1.0 - s.craw, 4.0) * dm;
            vec3 nh = s.N / s.len;
            vec3 dnh = s.v * dc;
            dN += (dnh - nh * dot(nh, dnh)) / s.len;
        }
    } else {
        dA = R * dI;
        dR = dot(dI, A - S);
    }
    g_refl[pix] = dA.x;
    g_refl[n + pix] = dA.y;
    g_refl[2u * n + pix] = dA.z;
    g_refl[3u * n + pix] = dR + pc.r_prior;
    if (ch == 7u) {
        g_refl[4u * n + pix] = dF0s.x;
        g_refl[5u * n + pix] = dF0s.y;
        g_refl[6u * n + pix] = dF0s.z;
    }
    if (pc.mask_weight != 0.0) {
        d_alpha += pc.mask_weight * (refl[ch * n + pix] - mask[pix]);
    }
    g_refl[ch * n + pix] = d_alpha + pc.alpha_prior;
    g_refl[(ch + 1u) * n + pix] = g_in[4u * n + pix];
    g_refl[(ch + 2u) * n + pix] = dN.x;
    g_refl[(ch + 3u) * n + pix] = dN.y;
    g_refl[(ch + 4u) * n + pix] = dN.z;
    g_refl[(ch + 5u) * n + pix] = g_in[8u * n + pix];
    g_refl[(ch + 6u) * n + pix] = g_in[9u * n + pix];
    if (pc.scat_grad != 0u) {
        vec3 dS = (1.0 - R) * dI;
        g_scat[pix] = dS.x;
        g_scat[n + pix] = dS.y;
        g_scat[2u * n + pix] = dS.z;
    }
}
