#version 460
// Deferred composite, forward (composite_common.glsl): one invocation per pixel.
#include "reflection/composite_common.glsl"

layout(std430, binding = 0) readonly buffer Scat { float scat[]; };
layout(std430, binding = 1) readonly buffer Refl { float refl[]; };
layout(std430, binding = 2) writeonly buffer LossIn { float loss_in[]; };

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = npix();
    if (pix >= n) {
        return;
    }
    uint ch = pc.channels;
    float R = refl[3u * n + pix];
    vec3 A = vec3(refl[pix], refl[n + pix], refl[2u * n + pix]);
    vec3 S = vec3(scat[pix], scat[n + pix], scat[2u * n + pix]);
    vec3 I_refl = A;
    if (pc.schlick != 0u) {
        float alpha = refl[ch * n + pix];
        vec3 F0 = vec3(refl[4u * n + pix], refl[5u * n + pix], refl[6u * n + pix]) / max(alpha, F0_EPS);
        vec3 N = vec3(refl[(ch + 2u) * n + pix], refl[(ch + 3u) * n + pix], refl[(ch + 4u) * n + pix]);
        float len = length(N);
        float c = len > NORMAL_EPS ? clamp(dot(N / len, pixel_view_dir(pix)), 0.0, 1.0) : 1.0;
        float m = pow(1.0 - c, 5.0);
        I_refl = (F0 + (1.0 - F0) * m) * A;
    }
    vec3 I = (1.0 - R) * S + R * I_refl;
    loss_in[pix] = I.x;
    loss_in[n + pix] = I.y;
    loss_in[2u * n + pix] = I.z;
    for (uint k = 0u; k < 7u; k++) {
        loss_in[(3u + k) * n + pix] = refl[(ch + k) * n + pix];
    }
}
