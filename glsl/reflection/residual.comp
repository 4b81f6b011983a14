#version 460
// The Stage I residual (paper eq. residual): r = I_gt - I_scat per pixel
// and channel (3 planes), and its magnitude mean_c |r_c| (a fourth plane).
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Target { float target[]; };
layout(std430, binding = 1) readonly buffer Scat { float scat[]; };
layout(std430, binding = 2) writeonly buffer Residual { float residual[]; };
layout(push_constant) uniform Push {
    uint pixels;
} pc;

void main() {
    uint p = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pc.pixels;
    if (p >= n) {
        return;
    }
    float m = 0.0;
    for (uint c = 0u; c < 3u; c++) {
        float r = target[c * n + p] - scat[c * n + p];
        residual[c * n + p] = r;
        m += abs(r);
    }
    residual[3u * n + p] = m / 3.0;
}
