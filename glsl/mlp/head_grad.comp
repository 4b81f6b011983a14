#version 460
// The head's pre-activation gradient, out of place: dZ = dY * Y (1 - Y)
// (the sigmoid's derivative), once per backward (pipelines/src/mlp), so
// that the head's weight- and input-gradient products read dZ without
// loading Y again for every block of columns they cover. The hidden
// layers' ReLU derivative is taken where their output gradient is written
// (the input-gradient product's epilogue, c_act 3 in mlp/gemm*.comp).
// Elements e < n OUT: z[e] = d[off + e] * (y[off + e] (1 - y[off + e])),
// with n_count != 0 n = min(n, rows[0]) (a count a kernel wrote).
#include "common.glsl"

layout(std430, binding = 0) readonly buffer D { float d[]; };
layout(std430, binding = 1) readonly buffer Y { float y[]; };
layout(std430, binding = 2) writeonly buffer Z { float z[]; };
layout(std430, binding = 3) readonly buffer Rows { uint rows[]; };
layout(push_constant) uniform Push {
    uint n;
    uint off;
    uint n_count;
} pc;

const uint OUT = 3u;

void main() {
    uint e = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pc.n_count != 0u ? min(pc.n, rows[0]) : pc.n;
    if (e >= n * OUT) {
        return;
    }
    float s = y[pc.off + e];
    z[e] = d[pc.off + e] * (s * (1.0 - s));
}
