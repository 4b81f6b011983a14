#version 460
// High-frequency loss, gradient (loss/hf_select.comp): for the pixels with
// e >= tau, grad[c] += weight sign(I_c - I_gt_c) / (3 count); one writer
// per pixel and plane.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) readonly buffer Target { float target[]; };
layout(std430, binding = 2) readonly buffer Stats { float stats[]; };
layout(std430, binding = 3) buffer Grad { float grad[]; };
layout(push_constant) uniform Push {
    uint n;
    float weight;
} pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pc.n;
    if (i >= n) {
        return;
    }
    vec3 d = vec3(render[i] - target[i], render[n + i] - target[n + i], render[2u * n + i] - target[2u * n + i]);
    float e = abs(d.x) + abs(d.y) + abs(d.z);  // 3 e, as the selection keys it
    e = isnan(e) ? 0.0 : e;
    if (floatBitsToUint(e) < floatBitsToUint(stats[0])) {
        return;
    }
    float k = pc.weight / (3.0 * max(stats[1], 1.0));
    grad[i] += k * sign(d.x);
    grad[n + i] += k * sign(d.y);
    grad[2u * n + i] += k * sign(d.z);
}
