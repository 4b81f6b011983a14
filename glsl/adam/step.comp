#version 460
// Fused Adam step (PyTorch form) over one parameter buffer. Elements whose
// index modulo `stride` is below `split` use lr_a, the others lr_b (the SH
// DC and rest coefficients of a feature block). Only the first `active`
// elements of each block of `stride` are stepped (invocation t: block
// t / active, element t % active; n counts those): the SH coefficients of
// degrees not yet active have zero gradients and would not move. A
// non-finite gradient counts as zero, so one bad pixel cannot poison the
// parameters or the moments.
#include "common.glsl"

layout(std430, binding = 0) buffer Param { float param[]; };
layout(std430, binding = 1) readonly buffer Grad { float grad[]; };
layout(std430, binding = 2) buffer M { float m1[]; };
layout(std430, binding = 3) buffer V { float m2[]; };
layout(push_constant) uniform Push {
    uint n;
    uint stride;
    uint split;
    uint n_active;
    float lr_a;
    float lr_b;
    float beta1;
    float beta2;
    float eps;
    float bc1;  // 1 - beta1^t
    float bc2;  // 1 - beta2^t
} pc;

void main() {
    uint t = wg_linear() * WG + gl_LocalInvocationID.x;
    if (t >= pc.n) {
        return;
    }
    uint i = pc.n_active == pc.stride ? t : (t / pc.n_active) * pc.stride + t % pc.n_active;
    float g = grad[i];
    if (isnan(g) || isinf(g)) {
        g = 0.0;
    }
    float m = pc.beta1 * m1[i] + (1.0 - pc.beta1) * g;
    float v = pc.beta2 * m2[i] + (1.0 - pc.beta2) * g * g;
    m1[i] = m;
    m2[i] = v;
    float lr = (i % pc.stride) < pc.split ? pc.lr_a : pc.lr_b;
    float denom = sqrt(v) / sqrt(pc.bc2) + pc.eps;
    param[i] -= (lr / pc.bc1) * m / denom;
}
