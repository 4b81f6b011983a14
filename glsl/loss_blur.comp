#version 460
// One pass of the separable 11-tap Gaussian (sigma 1.5) of SSIM, zero padded
// ("same" size). Mode 0 blurs, per colour channel c, the five products
// (x, y, x^2, y^2, xy) of render x and target y into planes 5c..5c+4; mode 1
// blurs `nplanes` planes of `src`. The Gaussian is symmetric, so the same pass
// is its own adjoint (used for the SSIM backward).
#include "loss_common.glsl"

layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) readonly buffer Target { float target[]; };
layout(std430, binding = 2) readonly buffer Src { float src[]; };
layout(std430, binding = 3) writeonly buffer Dst { float dst[]; };

float value(uint plane, uint pix) {
    if (pc.mode == 1u) {
        return src[plane * pixels() + pix];
    }
    uint c = plane / 5u;
    uint k = plane % 5u;
    float x = render[c * pixels() + pix];
    float y = target[c * pixels() + pix];
    if (k == 0u) return x;
    if (k == 1u) return y;
    if (k == 2u) return x * x;
    if (k == 3u) return y * y;
    return x * y;
}

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pixels();
    if (i >= n * pc.nplanes) {
        return;
    }
    uint plane = i / n;
    uint pix = i % n;
    int x = int(pix % pc.width);
    int y = int(pix / pc.width);
    float acc = 0.0;
    for (int t = -SSIM_RADIUS; t <= SSIM_RADIUS; t++) {
        int xx = pc.dir == 0u ? x + t : x;
        int yy = pc.dir == 0u ? y : y + t;
        if (xx < 0 || yy < 0 || xx >= int(pc.width) || yy >= int(pc.height)) {
            continue;
        }
        acc += SSIM_WEIGHTS[t + SSIM_RADIUS] * value(plane, uint(yy) * pc.width + uint(xx));
    }
    dst[plane * n + pix] = acc;
}
