#version 460
// A hidden layer's output gradient turned into its pre-activation gradient
// in place, dZ = dY * ReLU'(Z) = (Y > 0 ? dY : 0), once per backward
// (pipelines/src/mlp), so that the weight- and input-gradient products read
// dZ without loading Y again for every block of columns they cover.
// Elements: d[i width + j] with Y at y[i y_ld + j], i < n (with n_count != 0
// n = min(n, rows[0]), a count a kernel wrote), j < width.
#include "common.glsl"

layout(std430, binding = 0) buffer D { float d[]; };
layout(std430, binding = 1) readonly buffer Y { float y[]; };
layout(std430, binding = 2) readonly buffer Rows { uint rows[]; };
layout(push_constant) uniform Push {
    uint n;
    uint width;
    uint y_ld;
    uint n_count;
} pc;

void main() {
    uint e = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pc.n_count != 0u ? min(pc.n, rows[0]) : pc.n;
    if (e >= n * pc.width) {
        return;
    }
    uint i = e / pc.width, j = e % pc.width;
    float v = d[e];
    d[e] = y[i * pc.y_ld + j] > 0.0 ? v : 0.0;
}
