#version 460
// Fourier features of the light field's inputs (paper §3.4, NeRF style):
// gamma(a) = [a, sin(2^0 pi a), cos(2^0 pi a), ..., sin(2^(L-1) pi a),
// cos(2^(L-1) pi a)], each term over the 3 components (3 + 6L floats).
// The argument reduction: mlp/encoding.glsl.
//
// Samples: 6 floats each (x normalized, unit w), from sample `base` on (a
// block of the samples: pipelines/src/mlp `Block`). Writes gamma(x) to the
// first layer's input (row stride 3 + 6 L_x) and gamma(x), gamma(w) to the
// skip layer's input after its first `width` columns, rows from 0.
#include "common.glsl"
#include "mlp/encoding.glsl"

layout(std430, binding = 0) readonly buffer Samples { float samples[]; };
layout(std430, binding = 1) writeonly buffer In0 { float in0[]; };
layout(std430, binding = 2) writeonly buffer Cat { float cat[]; };
// With n_count != 0 only the first min(n, rows[0]) samples (a count a
// kernel wrote).
layout(std430, binding = 3) readonly buffer Rows { uint rows[]; };
layout(push_constant) uniform Push {
    uint n;
    uint levels_x;
    uint levels_w;
    uint width;
    uint n_count;
    uint base;
} pc;

void main() {
    uint s = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pc.n_count != 0u ? min(pc.n, rows[0]) : pc.n;
    if (s >= n) {
        return;
    }
    uint dx = 3u + 6u * pc.levels_x, dw = 3u + 6u * pc.levels_w;
    uint cat_w = pc.width + dx + dw;
    uint o0 = s * dx, oc = s * cat_w + pc.width;
    for (uint part = 0u; part < 2u; part++) {
        uint levels = part == 0u ? pc.levels_x : pc.levels_w;
        uint oc_p = oc + (part == 0u ? 0u : dx);
        for (uint d = 0u; d < 3u; d++) {
            float v = samples[6u * (pc.base + s) + 3u * part + d];
            if (part == 0u) {
                in0[o0 + d] = v;
            }
            cat[oc_p + d] = v;
            for (uint k = 0u; k < levels; k++) {
                vec2 sc = sincos_pi(v, k);
                uint fs = 3u + 6u * k + d, fc = fs + 3u;
                if (part == 0u) {
                    in0[o0 + fs] = sc.x;
                    in0[o0 + fc] = sc.y;
                }
                cat[oc_p + fs] = sc.x;
                cat[oc_p + fc] = sc.y;
            }
        }
    }
}
