#version 460
// Stage III composite, forward (lightfield/common.glsl): one invocation per
// pixel. Writes the loss input: the composite colour, then the reflection
// render's alpha..distortion planes (a 3-channel render's layout).
#include "lightfield/common.glsl"

layout(std430, binding = 1) readonly buffer Scat { float scat[]; };
layout(std430, binding = 2) readonly buffer SampleOf { uint sample_of[]; };
layout(std430, binding = 3) readonly buffer Phi { float phi[]; };
layout(std430, binding = 4) writeonly buffer LossIn { float loss_in[]; };

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = npix();
    if (pix >= n) {
        return;
    }
    uint s = sample_of[pix];
    vec3 S = vec3(scat[pix], scat[n + pix], scat[2u * n + pix]);
    vec3 I = S;
    if (s != NONE) {
        vec3 P = vec3(phi[3u * s], phi[3u * s + 1u], phi[3u * s + 2u]);
        float R = refl_r(pix);
        I = (1.0 - R) * S + R * fresnel_terms(pix).F * P;
    }
    loss_in[pix] = I.x;
    loss_in[n + pix] = I.y;
    loss_in[2u * n + pix] = I.z;
    for (uint k = 0u; k < 7u; k++) {
        loss_in[(3u + k) * n + pix] = refl[(CH + k) * n + pix];
    }
}
