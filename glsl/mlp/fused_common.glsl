// The fused light-field kernels' shared pieces (mlp/fused_forward.comp,
// mlp/fused_backward.comp; pipelines/src/mlp `Gemm::Fused`).
//
// A workgroup of 64 invocations owns a block of BR = 8 RB sample rows and
// keeps their activations in shared memory from the encoding to the head
// (tiny-cuda-nn's fully fused MLP, without tensor cores): every layer's
// product C (BR x J) = A (BR x K) B (K x J) is summed by the invocations as
// an 8 x 8 grid, invocation (rl, cl) owning the rows rl + 8 r (r < RB) and
// the columns cl + 8 c (c < CB) in registers, A read from the shared
// activations and B, K rows at a time, staged through shared memory. Each
// element is summed by one invocation in increasing k, acc += a b, the bias
// last (times an implicit 1), as the GEMM kernels sum it: the results are
// the same bits as theirs (tests/tests/mlp.rs).
#ifndef TGS_MLP_FUSED_COMMON_GLSL
#define TGS_MLP_FUSED_COMMON_GLSL

#include "common.glsl"
#extension GL_EXT_control_flow_attributes : require

// The workgroup (WG, spec constant 0) is 64 invocations: the 8 x 8 grid
// (pipelines/src/mlp/fused.rs sets it).
// Rows per invocation (the block is 8 RB rows).
layout(constant_id = 3) const uint RB = 4;
// Columns per invocation: layers up to 8 CB wide.
layout(constant_id = 4) const uint CB = 8;
// Floats per row of the shared activations.
layout(constant_id = 5) const uint STRIDE = 8;
// Rows of B staged in shared memory at a time.
layout(constant_id = 6) const uint KC = 8;

const uint BR = 8u * RB;
const uint WMAX = 8u * CB;
const uint OUT = 3u;

layout(push_constant) uniform Push {
    // Samples of this block (with n_count != 0, at most: min(n, rows[0])).
    uint n;
    // The block's first sample in `samples`, `out` and `d_out`; the
    // activations' rows count from 0.
    uint base;
    uint n_count;
    uint width;
    uint depth;
    uint skip;
    uint levels_x;
    uint levels_w;
    // Floats between two layers in the stacked activation buffers.
    uint layer_stride;
} pc;

shared float ws[KC * WMAX];

uint dx() {
    return 3u + 6u * pc.levels_x;
}
uint dw() {
    return 3u + 6u * pc.levels_w;
}
uint cat_width() {
    return pc.width + dx() + dw();
}
uint fan_in(uint l) {
    return l == 0u ? dx() : (l == pc.skip ? cat_width() : pc.width);
}
uint fan_out(uint l) {
    return l == pc.depth ? OUT : pc.width;
}
// Start of layer l's [W | b] (fan_out rows of fan_in + 1) in the parameters.
uint layer_offset(uint l) {
    uint off = 0u;
    for (uint k = 0u; k < l; k++) {
        off += fan_out(k) * (fan_in(k) + 1u);
    }
    return off;
}
#endif
