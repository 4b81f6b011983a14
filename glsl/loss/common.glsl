// Shared definitions of the image-loss kernels (loss_*.comp): one invocation
// per pixel (or per pixel and plane), planar images of width * height floats.
#ifndef TGS_LOSS_COMMON_GLSL
#define TGS_LOSS_COMMON_GLSL
#include "common.glsl"

layout(push_constant) uniform Push {
    uint width;
    uint height;
    uint channels;   // colour channels C (the first C planes of the render)
    uint pad1;
    float fx, fy, cx, cy;
    float w_l1;      // (1 - lambda_ssim)
    float w_ssim;    // lambda_ssim
    float w_normal;  // lambda_normal (0: normal consistency off)
    float w_dist;    // lambda_dist
    uint mode;       // blur: 0 = products of render and target, 1 = planes
    uint pad0;
    uint plane_alpha;
    uint plane_depth;
    uint plane_normal;
    uint plane_median;
    uint plane_dist;
    uint pad;
} pc;

uint pixels() {
    return pc.width * pc.height;
}

// SSIM constants (Wang et al.; 3DGS/2DGS utils/loss_utils.py).
const float SSIM_C1 = 0.0001;
const float SSIM_C2 = 0.0009;
const int SSIM_RADIUS = 5;
// exp(-t^2 / (2 sigma^2)) with sigma 1.5 for t = -5..5, normalised to sum 1 (computed in
// f64; constants instead of 22 exp() per output pixel).
const float SSIM_WEIGHTS[11] = float[11](
    1.028380084e-03, 7.598758135e-03, 3.600077213e-02, 1.093606895e-01, 2.130055377e-01, 2.660117249e-01,
    2.130055377e-01, 1.093606895e-01, 3.600077213e-02, 7.598758135e-03, 1.028380084e-03);

// The taps k of the window centred at coordinate v on an axis of length len
// that fall inside it: k in [lo, hi] (zero padding skips the others).
ivec2 ssim_taps(int v, int len) {
    return ivec2(max(-SSIM_RADIUS, -v), min(SSIM_RADIUS, len - 1 - v));
}

// Deterministic workgroup sum of one value per invocation (fixed tree order).
shared float s_red[256];
float wg_sum(float v) {
    uint lid = gl_LocalInvocationID.x;
    barrier();
    s_red[lid] = v;
    barrier();
    for (uint s = WG / 2u; s > 0u; s >>= 1u) {
        if (lid < s) {
            s_red[lid] += s_red[lid + s];
        }
        barrier();
    }
    return s_red[0];
}

#endif
