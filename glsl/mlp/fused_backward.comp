#version 460
// The light field's input gradients fused into one kernel (pipelines/src/mlp
// `Gemm::Fused`; the scheme in mlp/fused_common.glsl): a workgroup takes
// its block's output gradient, turns it into the head's dZ = dY Y (1 - Y)
// (as mlp/head_grad.comp), and walks the layers down in shared memory,
// dZ_{l-1} = (dZ_l W_l[:, :width]) * ReLU'(Y_{l-1}) (as the GEMMs' input
// gradient with its ReLU epilogue; the skip layer's encoded columns get no
// gradient). Every layer's dZ goes to `dz` (layer l at l layer_stride, row
// stride its width; the head's 3 wide) for the weight gradients, which
// stay split-k GEMM products with per-chunk partials summed in a fixed
// order (tiny-cuda-nn too leaves them to a GEMM): a workgroup's partials
// of every weight would not fit its shared memory.
#include "mlp/fused_common.glsl"

layout(std430, binding = 0) readonly buffer Params { float params[]; };
// Phi and dL/dPhi, RGB per sample from sample `base` on.
layout(std430, binding = 1) readonly buffer Out { float outs[]; };
layout(std430, binding = 2) readonly buffer DOut { float d_out[]; };
// The forward's activations: the skip layer's input (its first `width`
// columns the layer before it) and the other hidden layers' outputs.
layout(std430, binding = 3) readonly buffer Cat { float cat[]; };
layout(std430, binding = 4) readonly buffer Stack { float stack[]; };
layout(std430, binding = 5) writeonly buffer Dz { float dz[]; };
layout(std430, binding = 6) readonly buffer Rows { uint rows[]; };

// This block's dZ of the layer being walked, WMAX floats per row.
shared float dzs[BR * WMAX];

void main() {
    uint n = pc.n_count != 0u ? min(pc.n, rows[0]) : pc.n;
    uint r0 = wg_linear() * BR;
    if (r0 >= n) {
        return;
    }
    uint m = min(BR, n - r0);
    uint t = gl_LocalInvocationID.x, cl = t % 8u, rl = t / 8u;
    uint width = pc.width, cat_w = cat_width();

    // The head: rows past the block's samples get no gradient.
    for (uint e = t; e < BR * OUT; e += WG) {
        uint i = e / OUT, j = e % OUT, row = r0 + i;
        float z = 0.0;
        if (i < m) {
            float s = outs[(pc.base + row) * OUT + j];
            z = d_out[(pc.base + row) * OUT + j] * (s * (1.0 - s));
            dz[pc.depth * pc.layer_stride + row * OUT + j] = z;
        }
        dzs[i * WMAX + j] = z;
    }

    uint nc = (width + 7u) / 8u;
    for (uint l = pc.depth; l > 0u; l--) {
        uint kdim = fan_out(l), ld = fan_in(l) + 1u, woff = layer_offset(l);
        float acc[RB][CB];
        [[unroll]] for (uint r = 0u; r < RB; r++) {
            [[unroll]] for (uint c = 0u; c < CB; c++) {
                acc[r][c] = 0.0;
            }
        }
        for (uint k0 = 0u; k0 < kdim; k0 += KC) {
            uint kn = min(KC, kdim - k0);
            barrier();
            // B(k, j) = W[k][j] for the h columns j < width: rows of W, read
            // along j.
            for (uint e = t; e < KC * width; e += WG) {
                uint kc = e / width, j = e % width;
                if (kc < kn) {
                    ws[kc * WMAX + j] = params[woff + (k0 + kc) * ld + j];
                }
            }
            barrier();
            for (uint kc = 0u; kc < kn; kc++) {
                uint k = k0 + kc;
                float a[RB];
                [[unroll]] for (uint r = 0u; r < RB; r++) {
                    a[r] = dzs[(rl + 8u * r) * WMAX + k];
                }
                [[unroll]] for (uint c = 0u; c < CB; c++) {
                    if (c < nc) {
                        float b = cl + 8u * c < width ? ws[kc * WMAX + cl + 8u * c] : 0.0;
                        [[unroll]] for (uint r = 0u; r < RB; r++) {
                            acc[r][c] += a[r] * b;
                        }
                    }
                }
            }
        }
        // Every invocation has read this layer's dZ.
        barrier();
        uint below = l - 1u;
        [[unroll]] for (uint r = 0u; r < RB; r++) {
            uint i = rl + 8u * r, row = r0 + i;
            [[unroll]] for (uint c = 0u; c < CB; c++) {
                uint j = cl + 8u * c;
                if (c < nc && j < width) {
                    float v = 0.0;
                    if (i < m) {
                        float y = below + 1u == pc.skip ? cat[row * cat_w + j] : stack[below * pc.layer_stride + row * width + j];
                        v = y > 0.0 ? acc[r][c] : 0.0;
                        dz[below * pc.layer_stride + row * width + j] = v;
                    }
                    dzs[i * WMAX + j] = v;
                }
            }
        }
    }
}
