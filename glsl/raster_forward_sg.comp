#version 460
// Per-pixel 2DGS forward in ONE SUBGROUP per tile (for CPU drivers; see
// raster_backward_sg.comp): invocation l owns the PPT = 256 / WG pixels
// l, l + WG, ... of the 16x16 tile with their blending state in registers
// and walks the tile's splats front to back, reading each splat straight
// from the projection buffer (the same address in every invocation): no
// shared-memory staging, no barriers. The math, the outputs and the span
// handling are raster_forward.comp's (method-notes §1.5); the walk stops
// when every pixel of the tile is saturated.
#include "common.glsl"
#include "raster_common.glsl"

layout(constant_id = 6) const uint PPT = 32;  // pixels per invocation; WG * PPT = 256

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, binding = 2) readonly buffer Vals { uint vals[]; };
layout(std430, binding = 3) readonly buffer Gid { uint gid[]; };
layout(std430, binding = 4) readonly buffer ProjIn { float proj[]; };
layout(std430, binding = 5) readonly buffer FeatIn { float pfeat[]; };
layout(std430, binding = 6) buffer Out { float outp[]; };
layout(std430, binding = 7) buffer FState { float fstate[]; };
layout(std430, binding = 8) buffer UState { uint ustate[]; };
layout(std430, binding = 9) buffer Stats { uint stats[]; };

void main() {
    uint tile = wg_linear();
    if (tile >= pc.tiles_x * pc.tiles_y) {
        return;
    }
    uvec2 range = ranges[tile];
    uint start = range.x + pc.span_index * pc.span;
    if (pc.span_index > 0u && start >= range.y) {
        return;
    }
    uint end = min(range.y, start + pc.span);
    bool last_span = end >= range.y;
    uint lid = gl_LocalInvocationID.x;
    if (!last_span && pc.span_index + 1u == pc.spans && lid == 0u) {
        stats[1] = 1u;  // this tile needs more span passes than were recorded
    }
    uint tx = tile % pc.tiles_x, ty = tile / pc.tiles_x;
    uint plane = pc.width * pc.height;

    vec2 pfs[PPT];
    uint pxs[PPT];
    bool ins[PPT], dones[PPT];
    float accs[PPT * CH];
    float Ts[PPT], Ds[PPT], M1s[PPT], M2s[PPT], dists[PPT], meds[PPT];
    vec3 Ns[PPT];
    uint lasts[PPT], med_is[PPT];
    bool all_done = true;
    for (uint k = 0u; k < PPT; k++) {
        uint i = lid + k * WG;
        uvec2 pix = uvec2(tx * TILE + (i % TILE), ty * TILE + (i / TILE));
        bool inside = pix.x < pc.width && pix.y < pc.height;
        uint px = pix.y * pc.width + pix.x;
        pfs[k] = vec2(pix);
        pxs[k] = px;
        ins[k] = inside;
        bool resume = inside && pc.span_index > 0u;
        for (uint c = 0u; c < CH; c++) {
            accs[k * CH + c] = resume ? outp[c * plane + px] : 0.0;
        }
        Ds[k] = resume ? outp[P_DEPTH * plane + px] : 0.0;
        Ns[k] = resume ? vec3(outp[P_NORMAL * plane + px], outp[(P_NORMAL + 1u) * plane + px], outp[(P_NORMAL + 2u) * plane + px]) : vec3(0.0);
        meds[k] = resume ? outp[P_MEDIAN * plane + px] : 0.0;
        dists[k] = resume ? outp[P_DIST * plane + px] : 0.0;
        Ts[k] = resume ? fstate[px] : 1.0;
        M1s[k] = resume ? fstate[plane + px] : 0.0;
        M2s[k] = resume ? fstate[2u * plane + px] : 0.0;
        lasts[k] = resume ? ustate[px] : 0u;
        med_is[k] = resume ? ustate[plane + px] : 0xFFFFFFFFu;
        dones[k] = !inside || (resume && ustate[2u * plane + px] != 0u);
        all_done = all_done && dones[k];
    }

    float feat[CH];
    for (uint q = start; q < end && !subgroupAll(all_done); q++) {
        uint g = gid[vals[q]];
        uint o = 16u * g;
        vec3 tu = vec3(proj[o], proj[o + 1u], proj[o + 2u]);
        vec3 tv = vec3(proj[o + 3u], proj[o + 4u], proj[o + 5u]);
        vec3 tw = vec3(proj[o + 6u], proj[o + 7u], proj[o + 8u]);
        vec2 mu = vec2(proj[o + 9u], proj[o + 10u]);
        vec3 nrm = vec3(proj[o + 11u], proj[o + 12u], proj[o + 13u]);
        float op = proj[o + 14u];
        for (uint c = 0u; c < CH; c++) {
            feat[c] = pfeat[g * CH + c];
        }
        all_done = true;
        for (uint k = 0u; k < PPT; k++) {
            if (dones[k]) {
                continue;
            }
            Hit h;
            bool hit = intersect(tu, tv, tw, mu, pfs[k], h);
            float alpha = hit ? min(ALPHA_MAX, op * h.g) : 0.0;
            if (alpha < ALPHA_MIN) {
                all_done = false;
                continue;
            }
            float T = Ts[k];
            float Tn = T * (1.0 - alpha);
            if (Tn < T_MIN) {
                dones[k] = true;
                continue;
            }
            all_done = false;
            float w = alpha * T;
            for (uint c = 0u; c < CH; c++) {
                accs[k * CH + c] += w * feat[c];
            }
            Ds[k] += w * h.z;
            Ns[k] += w * nrm;
            float m = ndc_depth(h.z);
            float M1 = M1s[k], M2 = M2s[k];
            dists[k] += w * (m * m * (1.0 - T) + M2 - 2.0 * m * M1);
            M1s[k] = M1 + w * m;
            M2s[k] = M2 + w * m * m;
            if (T > 0.5) {
                meds[k] = h.z;
                med_is[k] = q;
            }
            Ts[k] = Tn;
            lasts[k] = q + 1u;
        }
    }

    for (uint k = 0u; k < PPT; k++) {
        if (!ins[k]) {
            continue;
        }
        uint px = pxs[k];
        float T = Ts[k];
        for (uint c = 0u; c < CH; c++) {
            outp[c * plane + px] = accs[k * CH + c] + (last_span ? T * cam[20u + c] : 0.0);
        }
        outp[P_ALPHA * plane + px] = 1.0 - T;
        outp[P_DEPTH * plane + px] = Ds[k];
        outp[P_NORMAL * plane + px] = Ns[k].x;
        outp[(P_NORMAL + 1u) * plane + px] = Ns[k].y;
        outp[(P_NORMAL + 2u) * plane + px] = Ns[k].z;
        outp[P_MEDIAN * plane + px] = meds[k];
        outp[P_DIST * plane + px] = dists[k];
        fstate[px] = T;
        fstate[plane + px] = M1s[k];
        fstate[2u * plane + px] = M2s[k];
        ustate[px] = lasts[k];
        ustate[plane + px] = med_is[k];
        ustate[2u * plane + px] = dones[k] ? 1u : 0u;
    }
}
