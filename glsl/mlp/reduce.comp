#version 460
// Sum of the weight gradients' per-chunk partials in a fixed order:
// grad[i] = sum over z < chunks of part[z stride + i], z increasing.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Part { float part[]; };
layout(std430, binding = 1) writeonly buffer Grad { float grad[]; };
layout(push_constant) uniform Push {
    uint n;
    uint chunks;
    uint stride;
} pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    float s = 0.0;
    for (uint z = 0u; z < pc.chunks; z++) {
        s += part[z * pc.stride + i];
    }
    grad[i] = s;
}
