#version 460
// The light field's forward fused into one kernel (pipelines/src/mlp
// `Gemm::Fused`; the scheme in mlp/fused_common.glsl): a workgroup encodes
// its block's samples (mlp/encoding.glsl, as mlp/encode.comp does) into
// shared memory, runs every layer there, and writes Phi. It also writes
// what the backward reads, as the layer-by-layer path does: gamma(x) to
// `in0`, the skip layer's input to `cat`, the other hidden layers' outputs
// to `stack` (layer l at l layer_stride, row stride width).
//
// Shared activations, one row of STRIDE = cat_width per sample:
// [h (width) | gamma(x) | gamma(w)], the skip layer's input in the order
// it reads it; layer 0 reads gamma(x) from column `width` on, the others
// h (the skip layer all three); a layer's output overwrites h once every
// invocation has read its inputs.
#include "mlp/fused_common.glsl"
#include "mlp/encoding.glsl"

layout(std430, binding = 0) readonly buffer Samples { float samples[]; };
layout(std430, binding = 1) readonly buffer Params { float params[]; };
layout(std430, binding = 2) writeonly buffer In0 { float in0[]; };
layout(std430, binding = 3) writeonly buffer Cat { float cat[]; };
layout(std430, binding = 4) writeonly buffer Stack { float stack[]; };
layout(std430, binding = 5) writeonly buffer Out { float outs[]; };
// With n_count != 0 the block has min(n, rows[0]) samples (a count a kernel wrote).
layout(std430, binding = 6) readonly buffer Rows { uint rows[]; };

shared float act[BR * STRIDE];

void main() {
    uint n = pc.n_count != 0u ? min(pc.n, rows[0]) : pc.n;
    uint r0 = wg_linear() * BR;
    // A block past the samples (uniform) has nothing to do.
    if (r0 >= n) {
        return;
    }
    uint m = min(BR, n - r0);
    uint t = gl_LocalInvocationID.x, cl = t % 8u, rl = t / 8u;
    uint width = pc.width, cat_w = cat_width(), ndx = dx();

    // gamma(x), gamma(w): one invocation per (row, component); rows past
    // the block's samples encode its last sample and are never written out.
    for (uint e = t; e < BR * 6u; e += WG) {
        uint i = e / 6u, comp = e % 6u, part = comp / 3u, d = comp % 3u;
        uint row = r0 + min(i, m - 1u);
        float v = samples[6u * (pc.base + row) + comp];
        uint levels = part == 0u ? pc.levels_x : pc.levels_w;
        uint col = width + (part == 0u ? 0u : ndx);
        bool keep = i < m;
        act[i * STRIDE + col + d] = v;
        if (keep) {
            cat[row * cat_w + col + d] = v;
            if (part == 0u) {
                in0[row * ndx + d] = v;
            }
        }
        for (uint k = 0u; k < levels; k++) {
            vec2 sc = sincos_pi(v, k);
            uint fs = 3u + 6u * k + d, fc = fs + 3u;
            act[i * STRIDE + col + fs] = sc.x;
            act[i * STRIDE + col + fc] = sc.y;
            if (keep) {
                cat[row * cat_w + col + fs] = sc.x;
                cat[row * cat_w + col + fc] = sc.y;
                if (part == 0u) {
                    in0[row * ndx + fs] = sc.x;
                    in0[row * ndx + fc] = sc.y;
                }
            }
        }
    }

    uint woff = 0u;
    for (uint l = 0u; l <= pc.depth; l++) {
        uint kdim = fan_in(l), jdim = fan_out(l);
        uint acol = l == 0u ? width : 0u;
        // Column blocks holding a column of this layer (uniform).
        uint nc = (jdim + 7u) / 8u;
        float acc[RB][CB];
        [[unroll]] for (uint r = 0u; r < RB; r++) {
            [[unroll]] for (uint c = 0u; c < CB; c++) {
                acc[r][c] = 0.0;
            }
        }
        // k = kdim is the bias: A's implicit ones column.
        for (uint k0 = 0u; k0 <= kdim; k0 += KC) {
            uint kn = min(KC, kdim + 1u - k0);
            barrier();
            // B(k, j) = W[j][k]: consecutive invocations read consecutive k.
            for (uint e = t; e < KC * jdim; e += WG) {
                uint kc = e % KC, j = e / KC;
                if (kc < kn) {
                    ws[kc * WMAX + j] = params[woff + j * (kdim + 1u) + k0 + kc];
                }
            }
            barrier();
            for (uint kc = 0u; kc < kn; kc++) {
                uint k = k0 + kc;
                float a[RB];
                [[unroll]] for (uint r = 0u; r < RB; r++) {
                    a[r] = k == kdim ? 1.0 : act[(rl + 8u * r) * STRIDE + acol + k];
                }
                [[unroll]] for (uint c = 0u; c < CB; c++) {
                    if (c < nc) {
                        float b = cl + 8u * c < jdim ? ws[kc * WMAX + cl + 8u * c] : 0.0;
                        [[unroll]] for (uint r = 0u; r < RB; r++) {
                            acc[r][c] += a[r] * b;
                        }
                    }
                }
            }
        }
        // Every invocation has read this layer's inputs.
        barrier();
        [[unroll]] for (uint r = 0u; r < RB; r++) {
            uint i = rl + 8u * r, row = r0 + i;
            [[unroll]] for (uint c = 0u; c < CB; c++) {
                uint j = cl + 8u * c;
                if (c < nc && j < jdim) {
                    float v = acc[r][c];
                    if (l == pc.depth) {
                        v = 1.0 / (1.0 + exp(-v));
                        if (i < m) {
                            outs[(pc.base + row) * OUT + j] = v;
                        }
                    } else {
                        v = max(v, 0.0);
                        act[i * STRIDE + j] = v;
                        if (i < m) {
                            if (l + 1u == pc.skip) {
                                cat[row * cat_w + j] = v;
                            } else {
                                stack[l * pc.layer_stride + row * width + j] = v;
                            }
                        }
                    }
                }
            }
        }
        woff += jdim * (kdim + 1u);
        barrier();
    }
}
