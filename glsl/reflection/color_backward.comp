#version 460
// Backward of the per-Gaussian reflection colour: from the rasterizer's
// feature gradients to the raw material (written), the position and the
// quaternion (added to the rasterizer's geometry gradients: this Gaussian's
// own slots, one writer), and the environment texels: each Gaussian writes
// its four taps' gradients to its own slots 4i..4i+3 (key = texel index)
// for a sort by texel and a fixed-order per-texel sum (no atomics).
#define ENV_DEPTH_BINDING 11
#include "reflection/color_common.glsl"

layout(std430, binding = 4) readonly buffer DFeat { float dfeat[]; };
layout(std430, binding = 5) buffer GMeans { float g_means[]; };
layout(std430, binding = 6) buffer GQuats { vec4 g_quats[]; };
layout(std430, binding = 7) writeonly buffer GMaterial { float g_material[]; };
layout(std430, binding = 8) writeonly buffer TapKeys { uint tap_keys[]; };
layout(std430, binding = 9) writeonly buffer TapSlots { uint tap_slots[]; };
layout(std430, binding = 10) writeonly buffer TapGrads { float tap_grads[]; };

bool finite3(vec3 v) {
    return !any(isnan(v)) && !any(isinf(v));
}

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    vec3 p = gaussian_mean(i);
    ReflGeom g = refl_geom(p, quats[i]);
    EnvDir ed = env_dir(p, g.w);
    EnvTaps t = env_taps(ed.d, pc.res);
    vec3 u = env_raw(t);
    vec3 e = sigmoid3(u);
    vec3 f0 = gaussian_f0(i);
    float r = gaussian_r(i);

    uint b = pc.channels * i;
    vec3 dc = vec3(dfeat[b], dfeat[b + 1u], dfeat[b + 2u]);
    float dr = dfeat[b + 3u];
    vec3 df0 = pc.channels == 7u ? vec3(dfeat[b + 4u], dfeat[b + 5u], dfeat[b + 6u]) : vec3(0.0);
    vec3 de = dc;
    if (pc.schlick == 0u) {
        de = dc * f0;
        df0 += dc * e;
    }
    vec3 dmat = df0 * f0 * (1.0 - f0);
    g_material[4u * i] = dmat.x;
    g_material[4u * i + 1u] = dmat.y;
    g_material[4u * i + 2u] = dmat.z;
    g_material[4u * i + 3u] = dr * r * (1.0 - r);

    // Through the sigmoid to the pre-sigmoid value u = sum w_k T_k.
    vec3 du = de * e * (1.0 - e);
    vec3 dd = vec3(0.0); // dL/d(lookup direction)
    for (uint k = 0u; k < 4u; k++) {
        uint s = 4u * i + k;
        tap_keys[s] = t.idx[k];
        tap_slots[s] = s;
        vec3 gt = du * t.w[k];
        tap_grads[3u * s] = gt.x;
        tap_grads[3u * s + 1u] = gt.y;
        tap_grads[3u * s + 2u] = gt.z;
        dd += dot(du, env_texel(t.idx[k])) * t.dw[k];
    }
    // Through the parallax proxy (the identity without one).
    vec3 dp_proxy = vec3(0.0);
    vec3 dw = env_dir_backward(ed, g.w, dd, dp_proxy);
    // w = 2 (n.v) n - v.
    float nv = dot(g.n, g.v);
    vec3 dn = 2.0 * nv * dw + 2.0 * dot(dw, g.n) * g.v;
    vec3 dv = 2.0 * dot(dw, g.n) * g.n - dw;
    // v = (c - p) / |c - p|.
    vec3 dp = (g.vlen > 1e-20 ? -(dv - g.v * dot(g.v, dv)) / g.vlen : vec3(0.0)) + dp_proxy;
    // n = sgn t_w(q / |q|).
    vec3 dt = g.sgn * dn;
    vec4 q = g.q;
    float qr = q.x, qx = q.y, qy = q.z, qz = q.w;
    vec4 dqn = vec4(
        dot(dt, vec3(2.0 * qy, -2.0 * qx, 0.0)),
        dot(dt, vec3(2.0 * qz, -2.0 * qr, -4.0 * qx)),
        dot(dt, vec3(2.0 * qr, 2.0 * qz, -4.0 * qy)),
        dot(dt, vec3(2.0 * qx, 2.0 * qy, 0.0)));
    vec4 dq = g.qlen > 1e-15 ? (dqn - q * dot(q, dqn)) / g.qlen : vec4(0.0);
    if (finite3(dp) && !any(isnan(dq)) && !any(isinf(dq))) {
        g_means[3u * i] += dp.x;
        g_means[3u * i + 1u] += dp.y;
        g_means[3u * i + 2u] += dp.z;
        g_quats[i] += dq;
    }
}
