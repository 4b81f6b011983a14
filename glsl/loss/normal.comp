#version 460
// 2DGS normal consistency, first half (method-notes §1.6, §1.8): per pixel,
// the normal of the expected-depth map (view space, central differences,
// camera facing, 0 on the 1-pixel border) against the rendered normal:
//   L_n = lambda / pixels * sum (1 - alpha * N . s),  alpha detached.
// Writes dL/dN into the render gradient's normal planes, and dL/d(dy),
// dL/d(dx) of the two difference vectors per pixel to `scratch` (6 floats)
// for loss_grad to gather (no scatter, no atomics). Partial sums of
// (1 - alpha N.s) go to partials[4 * wg + 3].
#include "loss/common.glsl"

layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) writeonly buffer Scratch { float scratch[]; };
layout(std430, binding = 2) buffer GradOut { float grad_out[]; };
layout(std430, binding = 3) buffer Partials { float partials[]; };

// Expected depth below this coverage counts as empty (no depth, no gradient).
const float MIN_ALPHA = 1e-6;

vec3 point(int x, int y) {
    uint pix = uint(y) * pc.width + uint(x);
    float a = render[pc.plane_alpha * pixels() + pix];
    float z = a > MIN_ALPHA ? render[pc.plane_depth * pixels() + pix] / a : 0.0;
    return z * vec3((float(x) - pc.cx) / pc.fx, (float(y) - pc.cy) / pc.fy, 1.0);
}

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = pixels();
    float lsum = 0.0;
    if (pix < n) {
        int x = int(pix % pc.width);
        int y = int(pix / pc.width);
        vec3 N = vec3(render[(pc.plane_normal + 0u) * n + pix], render[(pc.plane_normal + 1u) * n + pix], render[(pc.plane_normal + 2u) * n + pix]);
        float a = render[pc.plane_alpha * n + pix];
        vec3 g_dy = vec3(0.0), g_dx = vec3(0.0), g_n = vec3(0.0);
        float loss = 1.0;
        bool interior = x > 0 && y > 0 && x + 1 < int(pc.width) && y + 1 < int(pc.height);
        if (interior) {
            vec3 dy = point(x, y + 1) - point(x, y - 1);
            vec3 dx = point(x + 1, y) - point(x - 1, y);
            vec3 c = cross(dy, dx);
            float len = length(c);
            if (len > 1e-20 && a > 0.0) {
                vec3 s = c / len;
                loss = 1.0 - a * dot(N, s);
                float k = pc.w_normal / float(n);
                g_n = -k * a * s;
                vec3 g_s = -k * a * N;
                vec3 g_c = (g_s - s * dot(s, g_s)) / len;
                g_dy = cross(dx, g_c);
                g_dx = cross(g_c, dy);
            }
        }
        for (uint k = 0u; k < 3u; k++) {
            grad_out[(pc.plane_normal + k) * n + pix] = g_n[k];
        }
        scratch[6u * pix + 0u] = g_dy.x; scratch[6u * pix + 1u] = g_dy.y; scratch[6u * pix + 2u] = g_dy.z;
        scratch[6u * pix + 3u] = g_dx.x; scratch[6u * pix + 4u] = g_dx.y; scratch[6u * pix + 5u] = g_dx.z;
        lsum = loss;
    }
    float t = wg_sum(lsum);
    if (gl_LocalInvocationID.x == 0u) {
        partials[4u * wg_linear() + 3u] = t;
    }
}
