#version 460
// The light-field MLP's one GEMM (pipelines/src/mlp): C = post(pre(A) B),
// tiled through shared memory, one 8 RB x 8 RB tile of C per workgroup of
// 64 invocations, each owning an RB x RB block (rows ty RB + r, columns
// tx RB + c; RB a multiple of 4). Every element of C is summed in increasing
// k by one invocation, so the result does not depend on the subgroup size or
// the workgroup schedule.
//
// The tiles in shared memory are vec4s: an invocation reads its RB rows of A
// and RB columns of B at one k as RB / 2 vec4 loads instead of 2 RB scalar
// ones. Measured on lavapipe (a load costs about as much for 4 floats as for
// 1 there), on 2,304 samples: the small network 0.52 -> 0.76 GFLOP/s, the
// paper network 1.25 -> 1.67 (perf/RESULTS.md, twenty-fifth session); the
// sums, and so the results, are bit-identical to the scalar tiles'.
//
// Elements: A(i, k) = a[a_off + i a_rs + k a_cs], B(k, j) likewise, with
// optional implicit ones: A(i, a_ones_k) = 1 (the bias column of an
// augmented input [X, 1]) and B(k, b_ones_j) = 1 (the column that turns a
// weight gradient's last column into the bias gradient). post: c_act 1
// ReLU, 2 sigmoid, 3 the ReLU's derivative at C's own place, C(i, j) =
// Y(i, j) > 0 ? C : 0 with Y at y_off + i y_rs + j y_cs (an input gradient
// written as the ReLU layer below's dZ).
//
// Rows on the GPU: with m_count != 0, C has min(m, rows[0]) rows (a sample
// count a kernel wrote, e.g. the light field's compacted list); the grid is
// written from the same count (mlp/grid.comp, an indirect dispatch), so the
// work follows the count without the host reading it back.
//
// The k range is split over workgroups in z: chunk z sums
// k in [z k_chunk, min((z + 1) k_chunk, kdim)) and writes its C at
// c_off + z c_zstride (the weight gradients' per-chunk partials). With
// k_count != 0 the k range is the samples too: kdim = min(kdim, rows[0])
// and k_chunk = weight_chunk(kdim) (mlp/chunks.glsl), the split the host
// would choose for that count; the workgroups walk the chunks in
// bit-reversed order (see main), and those past the last chunk do no work
// and write nothing (their partial slots are not summed).
#extension GL_EXT_control_flow_attributes : require
#include "mlp/chunks.glsl"

layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;
// Rows and columns of C per invocation (the tile is 8 RB x 8 RB).
layout(constant_id = 3) const uint RB = 4;

layout(std430, binding = 0) readonly buffer A { float a[]; };
layout(std430, binding = 1) readonly buffer B { float b[]; };
layout(std430, binding = 2) readonly buffer Y { float y[]; };
layout(std430, binding = 3) buffer C { float c[]; };
layout(std430, binding = 4) readonly buffer Rows { uint rows[]; };

layout(push_constant) uniform Push {
    uint m, n, kdim, k_chunk;
    uint a_off, a_rs, a_cs, a_ones_k;
    uint b_off, b_rs, b_cs, b_ones_j;
    uint y_off, y_rs, y_cs;
    uint c_off, c_rs, c_zstride, c_act;
    uint m_count;
    uint k_count;
} pc;

const uint TM = 8u * RB, TN = 8u * RB, TK = 16u;
const uint NONE = 0xffffffffu;

shared vec4 As[TK][TM / 4u];
shared vec4 Bs[TK][TN / 4u];

float load_a(uint i, uint k) {
    if (k == pc.a_ones_k) {
        return 1.0;
    }
    return a[pc.a_off + i * pc.a_rs + k * pc.a_cs];
}

float load_b(uint k, uint j) {
    if (j == pc.b_ones_j) {
        return 1.0;
    }
    return b[pc.b_off + k * pc.b_rs + j * pc.b_cs];
}

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint tx = lid % 8u, ty = lid / 8u;
    // Counted chunks: the grid (a power of two along z) is walked in
    // bit-reversed order, so that the busy workgroups (the first chunks)
    // spread over the grid. A driver that hands each thread a contiguous
    // range of workgroups (llvmpipe does) then balances them. (Counted rows
    // were once walked so too: 59 ms in grid order, 39 ms bit-reversed, 36
    // ms with the host count, forward on 2,340 of 4,096 samples on lavapipe;
    // their grid now follows the count.)
    uint row_tile = gl_WorkGroupID.y;
    uint zc = pc.k_count != 0u ? spread(gl_WorkGroupID.z, gl_NumWorkGroups.z) : gl_WorkGroupID.z;
    uint i0 = row_tile * TM, j0 = gl_WorkGroupID.x * TN;
    uint count = (pc.m_count | pc.k_count) != 0u ? rows[0] : 0u;
    uint m = pc.m_count != 0u ? min(pc.m, count) : pc.m;
    uint kdim = pc.kdim, k_chunk = pc.k_chunk;
    if (pc.k_count != 0u) {
        kdim = min(kdim, count);
        k_chunk = weight_chunk(kdim);
    }
    uint kbeg = zc * k_chunk;
    uint kend = min(kbeg + k_chunk, kdim);
    // A workgroup past the rows or the chunks (uniform per workgroup) has
    // nothing to do: an empty k range, and it writes nothing but chunk 0.
    if (i0 >= m || (zc > 0u && kbeg >= kdim)) {
        kend = kbeg;
    }
    float acc[RB][RB];
    [[unroll]] for (uint r = 0u; r < RB; r++) {
        [[unroll]] for (uint q = 0u; q < RB; q++) {
            acc[r][q] = 0.0;
        }
    }
    for (uint k0 = kbeg; k0 < kend; k0 += TK) {
        // 64 invocations stage TK x TM of A and of B, four rows (columns)
        // of one k per vec4.
        [[unroll]] for (uint e = 0u; e < TK * TM / 256u; e++) {
            uint idx = lid + 64u * e;
            uint kk = idx / (TM / 4u), i4 = idx % (TM / 4u);
            uint k = k0 + kk;
            vec4 va = vec4(0.0), vb = vec4(0.0);
            [[unroll]] for (uint t = 0u; t < 4u; t++) {
                uint i = i0 + 4u * i4 + t, j = j0 + 4u * i4 + t;
                va[t] = (k < kend && i < m) ? load_a(i, k) : 0.0;
                vb[t] = (k < kend && j < pc.n) ? load_b(k, j) : 0.0;
            }
            As[kk][i4] = va;
            Bs[kk][i4] = vb;
        }
        barrier();
        [[unroll]] for (uint kk = 0u; kk < TK; kk++) {
            float av[RB], bv[RB];
            [[unroll]] for (uint r4 = 0u; r4 < RB / 4u; r4++) {
                vec4 a4 = As[kk][ty * (RB / 4u) + r4];
                vec4 b4 = Bs[kk][tx * (RB / 4u) + r4];
                [[unroll]] for (uint t = 0u; t < 4u; t++) {
                    av[4u * r4 + t] = a4[t];
                    bv[4u * r4 + t] = b4[t];
                }
            }
            [[unroll]] for (uint r = 0u; r < RB; r++) {
                [[unroll]] for (uint q = 0u; q < RB; q++) {
                    acc[r][q] += av[r] * bv[q];
                }
            }
        }
        barrier();
    }
    uint base = pc.c_off + zc * pc.c_zstride;
    [[unroll]] for (uint r = 0u; r < RB; r++) {
        uint i = i0 + ty * RB + r;
        [[unroll]] for (uint q = 0u; q < RB; q++) {
            uint j = j0 + tx * RB + q;
            if (i < m && j < pc.n) {
                float v = acc[r][q];
                if (pc.c_act == 1u) {
                    v = max(v, 0.0);
                } else if (pc.c_act == 2u) {
                    v = 1.0 / (1.0 + exp(-v));
                } else if (pc.c_act == 3u) {
                    v = y[pc.y_off + i * pc.y_rs + j * pc.y_cs] > 0.0 ? v : 0.0;
                }
                c[base + i * pc.c_rs + j] = v;
            }
        }
    }
}
