#version 460
// Radix sort, final copy after an odd number of passes: the first n keys and
// values (n from params, on the GPU) back into the caller's buffers, leaving
// elements past n untouched.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer KeysIn { uint keys_in[]; };
layout(std430, binding = 2) readonly buffer ValsIn { uint vals_in[]; };
layout(std430, binding = 3) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 4) writeonly buffer ValsOut { uint vals_out[]; };

void main() {
    uint n = params[0];
    uint p = wg_linear();
    if (p >= params[1]) {
        return;
    }
    for (uint k = 0; k < KPT; k++) {
        uint i = p * WG * KPT + k * WG + gl_LocalInvocationID.x;
        if (i < n) {
            keys_out[i] = keys_in[i];
            vals_out[i] = vals_in[i];
        }
    }
}
