#version 460
// Texel gradients, pass 1 of 2. The taps' gradient slots are sorted by
// texel (stable radix sort, so slots of one texel stay in Gaussian order).
// Per chunk of CHUNK consecutive sorted entries, in order: the sum of the
// leading run (entries with the chunk's first key) and of the trailing run
// (entries with its last key), 3 floats each.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Keys { uint keys[]; };
layout(std430, binding = 1) readonly buffer Slots { uint slots[]; };
layout(std430, binding = 2) readonly buffer Grads { float grads[]; };
layout(std430, binding = 3) writeonly buffer Runs { float runs[]; };
layout(push_constant) uniform Push {
    uint count;   // sorted entries
    uint chunk;   // entries per chunk
} pc;

vec3 slot_grad(uint q) {
    uint s = slots[q];
    return vec3(grads[3u * s], grads[3u * s + 1u], grads[3u * s + 2u]);
}

void main() {
    uint j = wg_linear() * WG + gl_LocalInvocationID.x;
    uint a = j * pc.chunk;
    if (a >= pc.count) {
        return;
    }
    uint b = min(a + pc.chunk, pc.count);
    uint kf = keys[a], kl = keys[b - 1u];
    vec3 first = vec3(0.0), last = vec3(0.0);
    for (uint q = a; q < b && keys[q] == kf; q++) {
        first += slot_grad(q);
    }
    uint s = b;
    while (s > a && keys[s - 1u] == kl) {
        s--;
    }
    for (uint q = s; q < b; q++) {
        last += slot_grad(q);
    }
    runs[6u * j] = first.x;
    runs[6u * j + 1u] = first.y;
    runs[6u * j + 2u] = first.z;
    runs[6u * j + 3u] = last.x;
    runs[6u * j + 4u] = last.y;
    runs[6u * j + 5u] = last.z;
}
