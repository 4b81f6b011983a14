#version 460
// The horizontal pass of SSIM's separable 11-tap Gaussian (sigma 1.5, zero
// padded, "same" size); the vertical pass is summed where it is used
// (loss_ssim for the moments, loss_grad for the coefficients). One
// invocation per colour channel c and pixel, its taps loaded once:
//   mode 0: the five products (x, y, x^2, y^2, xy) of render x and target y
//           into planes 5c..5c+4;
//   mode 1: planes 3c..3c+2 of `src` (the SSIM coefficients; the Gaussian is
//           symmetric, so the same pass is its own adjoint).
// Taps outside the image are not visited, so each sum runs over its valid
// taps from left to right.
// variant: TEXEL
#include "loss/common.glsl"

// Variant TEXEL (CPU devices): the inputs read as uniform texel buffers,
// one gather on llvmpipe where a storage load loops over the lanes
// (perf/RESULTS.md, forty-first entry); the same sums.
#ifdef TEXEL
layout(binding = 0) uniform samplerBuffer render_t;
layout(binding = 1) uniform samplerBuffer target_t;
layout(binding = 2) uniform samplerBuffer src_t;
#define RENDER(at) texelFetch(render_t, int(at)).r
#define TARGET(at) texelFetch(target_t, int(at)).r
#define SRC(at) texelFetch(src_t, int(at)).r
#else
layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) readonly buffer Target { float target[]; };
layout(std430, binding = 2) readonly buffer Src { float src[]; };
#define RENDER(at) render[at]
#define TARGET(at) target[at]
#define SRC(at) src[at]
#endif
layout(std430, binding = 3) writeonly buffer Dst { float dst[]; };

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pixels();
    if (i >= n * pc.channels) {
        return;
    }
    uint c = i / n;
    uint pix = i % n;
    int x = int(pix % pc.width);
    ivec2 t = ssim_taps(x, int(pc.width));
    uint row = pix - uint(x);
    if (pc.mode == 0u) {
        float s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0, s4 = 0.0;
        for (int k = t.x; k <= t.y; k++) {
            float w = SSIM_WEIGHTS[k + SSIM_RADIUS];
            uint q = row + uint(x + k);
            float a = RENDER(c * n + q);
            float b = TARGET(c * n + q);
            s0 += w * a;
            s1 += w * b;
            s2 += w * (a * a);
            s3 += w * (b * b);
            s4 += w * (a * b);
        }
        dst[(5u * c + 0u) * n + pix] = s0;
        dst[(5u * c + 1u) * n + pix] = s1;
        dst[(5u * c + 2u) * n + pix] = s2;
        dst[(5u * c + 3u) * n + pix] = s3;
        dst[(5u * c + 4u) * n + pix] = s4;
    } else {
        float s0 = 0.0, s1 = 0.0, s2 = 0.0;
        for (int k = t.x; k <= t.y; k++) {
            float w = SSIM_WEIGHTS[k + SSIM_RADIUS];
            uint q = row + uint(x + k);
            s0 += w * SRC((3u * c + 0u) * n + q);
            s1 += w * SRC((3u * c + 1u) * n + q);
            s2 += w * SRC((3u * c + 2u) * n + q);
        }
        dst[(3u * c + 0u) * n + pix] = s0;
        dst[(3u * c + 1u) * n + pix] = s1;
        dst[(3u * c + 2u) * n + pix] = s2;
    }
}
