#version 460
// Per pixel: the loss gradient of every render plane except the normals
// (loss_normal writes those when normal consistency is on; zero otherwise).
//   colour: (1 - lambda) sign(x - y) / (pixels C) + A + 2 x B + y C', with
//           A, B, C' the blurred SSIM coefficients of loss_ssim (this
//           kernel sums the blur's vertical pass over loss_blur's rows);
//   alpha, depth: normal consistency through the expected depth D / alpha,
//           gathered from the four neighbours' difference gradients;
//   median: 0; distortion: lambda_dist / pixels.
#include "loss/common.glsl"

layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) readonly buffer Target { float target[]; };
layout(std430, binding = 2) readonly buffer CoefRows { float coef_rows[]; };
layout(std430, binding = 3) readonly buffer Scratch { float scratch[]; };
layout(std430, binding = 4) buffer GradOut { float grad_out[]; };

const float MIN_ALPHA = 1e-6;

vec3 g_dy(int x, int y) {
    if (x < 0 || y < 0 || x >= int(pc.width) || y >= int(pc.height)) return vec3(0.0);
    uint p = uint(y) * pc.width + uint(x);
    return vec3(scratch[6u * p], scratch[6u * p + 1u], scratch[6u * p + 2u]);
}
vec3 g_dx(int x, int y) {
    if (x < 0 || y < 0 || x >= int(pc.width) || y >= int(pc.height)) return vec3(0.0);
    uint p = uint(y) * pc.width + uint(x);
    return vec3(scratch[6u * p + 3u], scratch[6u * p + 4u], scratch[6u * p + 5u]);
}

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pixels();
    if (pix >= n) {
        return;
    }
    float k1 = pc.w_l1 / (float(n) * float(pc.channels));
    ivec2 t = ssim_taps(int(pix / pc.width), int(pc.height));
    for (uint c = 0u; c < pc.channels; c++) {
        float x = render[c * n + pix];
        float y = target[c * n + pix];
        float d = x - y;
        float g = k1 * (d > 0.0 ? 1.0 : (d < 0.0 ? -1.0 : 0.0));
        if (pc.w_ssim != 0.0) {
            float a = 0.0, b = 0.0, cc = 0.0;
            for (int k = t.x; k <= t.y; k++) {
                float w = SSIM_WEIGHTS[k + SSIM_RADIUS];
                uint q = uint(int(pix) + k * int(pc.width));
                a += w * coef_rows[(3u * c + 0u) * n + q];
                b += w * coef_rows[(3u * c + 1u) * n + q];
                cc += w * coef_rows[(3u * c + 2u) * n + q];
            }
            g += a + 2.0 * x * b + y * cc;
        }
        grad_out[c * n + pix] = g;
    }
    float g_alpha = 0.0, g_depth = 0.0;
    if (pc.w_normal != 0.0) {
        int x = int(pix % pc.width);
        int y = int(pix / pc.width);
        // P(x, y) enters dy of (x, y-1) with +, of (x, y+1) with -, and dx of (x-1, y) with +, of (x+1, y) with -.
        vec3 g_p = g_dy(x, y - 1) - g_dy(x, y + 1) + g_dx(x - 1, y) - g_dx(x + 1, y);
        float a = render[pc.plane_alpha * n + pix];
        if (a > MIN_ALPHA) {
            float g_z = dot(g_p, vec3((float(x) - pc.cx) / pc.fx, (float(y) - pc.cy) / pc.fy, 1.0));
            float d = render[pc.plane_depth * n + pix];
            g_depth = g_z / a;
            g_alpha = -g_z * d / (a * a);
        }
    } else {
        for (uint k = 0u; k < 3u; k++) {
            grad_out[(pc.plane_normal + k) * n + pix] = 0.0;
        }
    }
    grad_out[pc.plane_alpha * n + pix] = g_alpha;
    grad_out[pc.plane_depth * n + pix] = g_depth;
    grad_out[pc.plane_median * n + pix] = 0.0;
    grad_out[pc.plane_dist * n + pix] = pc.w_dist / float(n);
}
