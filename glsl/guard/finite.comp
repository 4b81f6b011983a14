#version 460
// Divergence guard: flag[slot] = stamp when any of the first n values of
// `data` is NaN, infinite or larger in magnitude than `limit`. Every
// invocation that finds one stores the same value (no atomics, no
// read-modify-write), so the flag is deterministic; the host gives each
// round of checks a new stamp, so no clearing pass is needed.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Data { float data[]; };
layout(std430, binding = 1) buffer Flag { uint flag[]; };
layout(push_constant) uniform Push {
    uint n;
    uint slot;
    float limit;
    uint stamp;
} pc;

void main() {
    uint t = wg_linear() * WG + gl_LocalInvocationID.x;
    if (t >= pc.n) {
        return;
    }
    float x = data[t];
    if (isnan(x) || isinf(x) || !(abs(x) <= pc.limit)) {
        flag[pc.slot] = pc.stamp;
    }
}
