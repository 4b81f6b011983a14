#version 460
// Texel gradients, pass 2 of 2: one invocation per texel sums its range
// [s, e) of the sorted slots in a fixed order: directly when the range lies
// in one chunk, else the trailing run of its first chunk, the leading runs
// (= totals) of the chunks in between, and the leading run of its last chunk
// (texel_chunks.comp). Loop trips stay below count / chunk + chunk.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, binding = 1) readonly buffer Slots { uint slots[]; };
layout(std430, binding = 2) readonly buffer Grads { float grads[]; };
layout(std430, binding = 3) readonly buffer Runs { float runs[]; };
layout(std430, binding = 4) writeonly buffer Out { float g_env[]; };
layout(push_constant) uniform Push {
    uint texels;
    uint chunk;
} pc;

vec3 run(uint j, uint which) {
    uint o = 6u * j + 3u * which;
    return vec3(runs[o], runs[o + 1u], runs[o + 2u]);
}

void main() {
    uint t = wg_linear() * WG + gl_LocalInvocationID.x;
    if (t >= pc.texels) {
        return;
    }
    uvec2 r = ranges[t];
    vec3 sum = vec3(0.0);
    if (r.y > r.x) {
        uint a = r.x / pc.chunk, b = (r.y - 1u) / pc.chunk;
        if (a == b) {
            for (uint q = r.x; q < r.y; q++) {
                uint s = slots[q];
                sum += vec3(grads[3u * s], grads[3u * s + 1u], grads[3u * s + 2u]);
            }
        } else {
            sum = run(a, 1u);
            for (uint j = a + 1u; j < b; j++) {
                sum += run(j, 0u);
            }
            sum += run(b, 0u);
        }
    }
    g_env[3u * t] = sum.x;
    g_env[3u * t + 1u] = sum.y;
    g_env[3u * t + 2u] = sum.z;
}
