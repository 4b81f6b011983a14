#version 460
// Radix sort, up-sweep: digit histogram of each partition of WG * KPT keys,
// written digit-major (hist[d * partitions + p]) so that one exclusive scan
// of `hist` yields every (digit, partition) output offset, in stable order.
#include "sort/common.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer Keys { uint keys[]; };
layout(std430, binding = 2) writeonly buffer Hist { uint hist[]; };

shared uint h[RADIX];

void main() {
    uint n = params[0];
    uint parts = params[1];
    uint p = wg_linear();
    if (p >= parts) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    for (uint d = t; d < RADIX; d += WG) {
        h[d] = 0u;
    }
    barrier();
    uint base = p * WG * KPT;
    for (uint k = 0; k < KPT; k++) {
        uint i = base + k * WG + t;
        if (i < n) {
            // Shared integer atomics: order-independent, so deterministic.
            atomicAdd(h[digit_of(keys[i])], 1u);
        }
    }
    barrier();
    for (uint d = t; d < RADIX; d += WG) {
        hist[d * parts + p] = h[d];
    }
}
