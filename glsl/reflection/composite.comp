#version 460
// Deferred composite, forward (composite_common.glsl): one invocation per pixel.
#include "reflection/composite_common.glsl"

layout(std430, binding = 2) writeonly buffer LossIn { float loss_in[]; };

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
    vec3 I_refl = pc.schlick != 0u ? schlick_terms(pix).F * A : A;
    vec3 I = (1.0 - R) * S + R * I_refl;
    loss_in[pix] = I.x;
    loss_in[n + pix] = I.y;
    loss_in[2u * n + pix] = I.z;
    for (uint k = 0u; k < 7u; k++) {
        loss_in[(3u + k) * n + pix] = refl[(ch + k) * n + pix];
    }
}
