#version 460
// Per pixel: the vertical pass of the moments' blur (over loss_blur's
// horizontal sums, valid taps top to bottom), SSIM of every colour channel
// from them, its gradient coefficients with respect to the blurred x, x^2
// and xy (scaled by -lambda_ssim / (pixels * C), blurred again by loss_blur
// and loss_grad), and workgroup partial sums of L1, squared error and SSIM
// (partials[4 * wg + 0..2]).
// variant: TEXEL
#include "loss/common.glsl"

// Variant TEXEL (CPU devices): the inputs read as uniform texel buffers,
// one gather on llvmpipe where a storage load loops over the lanes
// (perf/RESULTS.md, forty-first entry); the same sums.
#ifdef TEXEL
layout(binding = 0) uniform samplerBuffer render_t;
layout(binding = 1) uniform samplerBuffer target_t;
layout(binding = 2) uniform samplerBuffer rows_t;
#define RENDER(at) texelFetch(render_t, int(at)).r
#define TARGET(at) texelFetch(target_t, int(at)).r
#define ROWS(at) texelFetch(rows_t, int(at)).r
#else
layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) readonly buffer Target { float target[]; };
layout(std430, binding = 2) readonly buffer Rows { float rows[]; };
#define RENDER(at) render[at]
#define TARGET(at) target[at]
#define ROWS(at) rows[at]
#endif
layout(std430, binding = 3) writeonly buffer Coef { float coef[]; };
layout(std430, binding = 4) writeonly buffer Partials { float partials[]; };

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pixels();
    float l1 = 0.0, se = 0.0, ss = 0.0;
    if (pix < n) {
        float k = -pc.w_ssim / (float(n) * float(pc.channels));
        int y = int(pix / pc.width);
        ivec2 t = ssim_taps(y, int(pc.height));
        for (uint c = 0u; c < pc.channels; c++) {
            float mx = 0.0, my = 0.0, exx = 0.0, eyy = 0.0, exy = 0.0;
            for (int k = t.x; k <= t.y; k++) {
                float w = SSIM_WEIGHTS[k + SSIM_RADIUS];
                uint q = uint(int(pix) + k * int(pc.width));
                mx += w * ROWS((5u * c + 0u) * n + q);
                my += w * ROWS((5u * c + 1u) * n + q);
                exx += w * ROWS((5u * c + 2u) * n + q);
                eyy += w * ROWS((5u * c + 3u) * n + q);
                exy += w * ROWS((5u * c + 4u) * n + q);
            }
            float sxx = exx - mx * mx;
            float syy = eyy - my * my;
            float sxy = exy - mx * my;
            float a1 = 2.0 * mx * my + SSIM_C1;
            float a2 = 2.0 * sxy + SSIM_C2;
            float b1 = mx * mx + my * my + SSIM_C1;
            float b2 = sxx + syy + SSIM_C2;
            float s = (a1 * a2) / (b1 * b2);
            // Partial derivatives holding the (co)variances, then through them.
            float d_mx = 2.0 * my * a2 / (b1 * b2) - s * 2.0 * mx / b1;
            float d_sxx = -s / b2;
            float d_sxy = 2.0 * a1 / (b1 * b2);
            coef[(3u * c + 0u) * n + pix] = k * (d_mx - 2.0 * mx * d_sxx - my * d_sxy);
            coef[(3u * c + 1u) * n + pix] = k * d_sxx;
            coef[(3u * c + 2u) * n + pix] = k * d_sxy;
            float d = RENDER(c * n + pix) - TARGET(c * n + pix);
            l1 += abs(d);
            se += d * d;
            ss += s;
        }
    }
    float t0 = wg_sum(l1);
    float t1 = wg_sum(se);
    float t2 = wg_sum(ss);
    if (gl_LocalInvocationID.x == 0u) {
        uint w = wg_linear();
        partials[4u * w + 0u] = t0;
        partials[4u * w + 1u] = t1;
        partials[4u * w + 2u] = t2;
    }
}
