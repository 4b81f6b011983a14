#version 460
// The light-field MLP's GEMM, one row of C per invocation (pipelines/src/mlp
// Gemm::Rows, chosen on CPU devices): the same products, push constants and
// bindings as mlp/gemm.comp, and the same summation (each element of C
// summed in increasing k by one invocation, acc += a_ik b_kj), so its
// results are bit-identical to the tiled kernel's.
//
// Invocation t of a workgroup of WGX owns the RR rows i = WGX RR y + t +
// WGX r (r < RR) of C and the NB columns [x NB, x NB + NB) that the whole
// workgroup shares, RR x NB accumulators in registers. At each k it loads
// its rows' A(i, k) and multiplies them by B(k, j): those are the same for
// every invocation, so each group of SB lanes loads SB different columns
// and shares them by broadcast. A lane makes RR + NB / SB loads and NB
// broadcasts per RR NB multiply-adds. In the forward (A the layer's input
// rows, B the weights) and the input gradient (A = dZ, B = W) B is the
// weights; in the weight gradient (C = dZ^T [X, 1]: rows the outputs j, k
// the samples) it is the samples' input rows.
//
// Why: on lavapipe every load goes lane by lane (a scalar load each, with
// its bounds check) and a broadcast costs several multiply-adds; the tiled
// kernel's shared-memory reads and staging were its bottleneck (0.66
// GFLOP/s forward on the small network), this kernel runs it at 3.9
// (perf/RESULTS.md, twenty-eighth session). No branch sits in the inner
// loop for the same reason (a branch masks the loads inside it).
//
// Rows on the GPU (m_count, their grid from the count), chunks of k over z
// (k_count, walked bit-reversed): as in mlp/gemm.comp.
#extension GL_EXT_control_flow_attributes : require
#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_ballot : require
#include "mlp/chunks.glsl"

// Invocations per workgroup (spec constant 6).
layout(local_size_x_id = 6, local_size_y = 1, local_size_z = 1) in;
#define WGX (gl_WorkGroupSize.x)
// Columns of C per invocation.
layout(constant_id = 3) const uint NB = 16;
// Lanes that share their loads by broadcast: at most the smallest subgroup size.
layout(constant_id = 4) const uint SB = 4;
// Rows of C per invocation: rows i + WGX r, r < RR (the workgroup's WGX RR).
layout(constant_id = 5) const uint RR = 1;

// The operands A, B and Y are read as uniform texel buffers of floats:
// llvmpipe 22.3 fetches a texel for the lanes as one gather, where a
// storage-buffer load is a loop over the lanes with a branch, a bounds
// check and a store to the stack for each (its SSBO path; read from the
// JIT's machine code, forty-first session): the small network's products
// ran 1.6-1.8x faster so (perf/RESULTS.md). Bindings as in mlp/gemm.comp.
layout(binding = 0) uniform samplerBuffer a_t;
layout(binding = 1) uniform samplerBuffer b_t;
layout(binding = 2) uniform samplerBuffer y_t;
#define A_AT(at) texelFetch(a_t, int(at)).r
#define B_AT(at) texelFetch(b_t, int(at)).r
#define Y_AT(at) texelFetch(y_t, int(at)).r
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

// A(i, k); the implicit ones column reads a valid address and is replaced
// (a select, not a branch around the load).
float load_a(uint i, uint k) {
    uint kk = k == pc.a_ones_k ? 0u : k;
    float v = A_AT(pc.a_off + i * pc.a_rs + kk * pc.a_cs);
    return k == pc.a_ones_k ? 1.0 : v;
}

void main() {
    uint row_group = gl_WorkGroupID.y;
    uint zc = pc.k_count != 0u ? spread(gl_WorkGroupID.z, gl_NumWorkGroups.z) : gl_WorkGroupID.z;
    uint i = row_group * WGX * RR + gl_LocalInvocationID.x;
    uint j0 = gl_WorkGroupID.x * NB;
    uint count = (pc.m_count | pc.k_count) != 0u ? rows[0] : 0u;
    uint m = pc.m_count != 0u ? min(pc.m, count) : pc.m;
    uint kdim = pc.kdim, k_chunk = pc.k_chunk;
    if (pc.k_count != 0u) {
        kdim = min(kdim, count);
        k_chunk = weight_chunk(kdim);
    }
    uint kbeg = zc * k_chunk;
    uint kend = min(kbeg + k_chunk, kdim);
    // A workgroup past the chunks (uniform) has nothing to do: its partial
    // slot is not summed.
    if (zc > 0u && kbeg >= kdim) {
        return;
    }
    // A workgroup past the rows (uniform; a counted grid covers the
    // capacity) likewise.
    if (row_group * WGX * RR >= m) {
        return;
    }
    // Every invocation walks the same k (the broadcasts below need the
    // whole subgroup); a row past m reads row m - 1 and is not written.
    uint row[RR];
    [[unroll]] for (uint r = 0u; r < RR; r++) {
        row[r] = min(i + WGX * r, m - 1u);
    }
    // Columns past n (uniform): B is read as 0 there and C not written.
    uint nb = min(NB, pc.n - min(j0, pc.n));
    float acc[RR][NB];
    [[unroll]] for (uint r = 0u; r < RR; r++) {
        [[unroll]] for (uint q = 0u; q < NB; q++) {
            acc[r][q] = 0.0;
        }
    }
    uint jl = max(pc.n, 1u) - 1u;
    uint lane = gl_SubgroupInvocationID % SB;
    for (uint k = kbeg; k < kend; k++) {
        float av[RR];
        [[unroll]] for (uint r = 0u; r < RR; r++) {
            av[r] = load_a(row[r], k);
        }
        uint boff = pc.b_off + k * pc.b_rs;
        // Each lane loads one of SB columns; the SB values are broadcast.
        [[unroll]] for (uint g = 0u; g < NB / SB; g++) {
            uint j = j0 + SB * g + lane;
            uint jj = j == pc.b_ones_j ? 0u : min(j, jl);
            float bl = B_AT(boff + jj * pc.b_cs);
            bl = j == pc.b_ones_j ? 1.0 : (SB * g + lane < nb ? bl : 0.0);
            [[unroll]] for (uint t = 0u; t < SB; t++) {
                float bv = subgroupBroadcast(bl, t);
                [[unroll]] for (uint r = 0u; r < RR; r++) {
                    acc[r][SB * g + t] += av[r] * bv;
                }
            }
        }
    }
    [[unroll]] for (uint r = 0u; r < RR; r++) {
        uint ir = i + WGX * r;
        if (ir < m) {
            uint base = pc.c_off + zc * pc.c_zstride + ir * pc.c_rs + j0;
            [[unroll]] for (uint q = 0u; q < NB; q++) {
                if (q < nb) {
                    float v = acc[r][q];
                    if (pc.c_act == 1u) {
                        v = max(v, 0.0);
                    } else if (pc.c_act == 2u) {
                        v = 1.0 / (1.0 + exp(-v));
                    } else if (pc.c_act == 3u) {
                        v = Y_AT(pc.y_off + ir * pc.y_rs + (j0 + q) * pc.y_cs) > 0.0 ? v : 0.0;
                    }
                    c[base + q] = v;
                }
            }
        }
    }
}
