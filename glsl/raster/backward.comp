#version 460
// variant: RECORDS_BDA
// variant: COLOUR_ONLY
// variant: COLOUR_ONLY RECORDS_BDA
#ifdef RECORDS_BDA
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#endif
// Per-pixel 2DGS backward without atomics (method-notes §1.7, vulkan-notes
// §3.2). One 16x16 workgroup per tile walks the tile's splats back to front
// (transmittance recovered by division, as in the reference). For each splat
// every pixel forms its gradient record (KREC floats); the records are summed
// over each subgroup (subgroupAdd), the per-subgroup partials go to shared
// memory, and after a barrier they are summed in subgroup order and written
// to the intersection's own slot RECORDS[emission index]. Every slot is written
// by exactly one invocation, in a fixed order: bit-identical results run to
// run. Spans are processed last to first (one pass each); per-pixel state
// (T, S) is carried between passes in `bstate`.
//
// dL/dalpha_i = T_i V_i - S_i / (1 - alpha_i), where V_i combines every
// output's value for splat i with its upstream gradient and
// S_i = sum_{j>i} w_j V_j + T_final (g_C . background).
// COLOUR_ONLY: the feature gradients alone (see raster/backward_sg.comp).
#include "common.glsl"
#include "raster/common.glsl"
#include "raster/pixel_grad.glsl"

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, binding = 2) readonly buffer Vals { uint vals[]; };
layout(std430, binding = 3) readonly buffer Gid { uint gid[]; };
layout(std430, binding = 4) readonly buffer ProjIn { float proj[]; };
layout(std430, binding = 5) readonly buffer FeatIn { float pfeat[]; };
layout(std430, binding = 6) readonly buffer Out { float outp[]; };
layout(std430, binding = 7) readonly buffer FState { float fstate[]; };
layout(std430, binding = 8) readonly buffer UState { uint ustate[]; };
layout(std430, binding = 9) readonly buffer GradOut { float gout[]; };
layout(std430, binding = 10) buffer BState { float bstate[]; };
#define RECORDS_BINDING 11
#define RECORDS_ACCESS writeonly
#include "raster/records.glsl"

shared float part[MAX_SG * BATCH * KREC];
shared uint s_last[MAX_SG];

void main() {
    uint tile = wg_linear();
    if (tile >= pc.tiles_x * pc.tiles_y) {
        return;
    }
    uvec2 range = ranges[tile];
    uint start = range.x + pc.span_index * pc.span;
    if (start >= range.y) {
        return;
    }
    uint end = min(range.y, start + pc.span);
    bool last_span = end >= range.y;

    uint lid = gl_LocalInvocationID.x;
    uint tx = tile % pc.tiles_x, ty = tile / pc.tiles_x;
    uvec2 pix = uvec2(tx * TILE + (lid % TILE), ty * TILE + (lid / TILE));
    bool inside = pix.x < pc.width && pix.y < pc.height;
    uint plane = pc.width * pc.height;
    uint px = inside ? pix.y * pc.width + pix.x : 0u;
    vec2 pf = vec2(pix);

    float gC[CH];
    float bg_dot = 0.0;
    for (uint c = 0u; c < CH; c++) {
        gC[c] = inside ? gout[c * plane + px] : 0.0;
        bg_dot += gC[c] * cam[20u + c];
    }
    float gA = 0.0, gD = 0.0, gMed = 0.0, gDist = 0.0, Tf = 1.0, M1 = 0.0, M2 = 0.0;
    vec3 gN = vec3(0.0);
    uint last = 0u, med_i = 0xFFFFFFFFu;
    float T = 1.0, S = 0.0;
    if (inside) {
        gA = gout[P_ALPHA * plane + px];
        gD = gout[P_DEPTH * plane + px];
        gN = vec3(gout[P_NORMAL * plane + px], gout[(P_NORMAL + 1u) * plane + px], gout[(P_NORMAL + 2u) * plane + px]);
        gMed = gout[P_MEDIAN * plane + px];
        gDist = gout[P_DIST * plane + px];
        Tf = fstate[px];
        M1 = fstate[plane + px];
        M2 = fstate[2u * plane + px];
        last = ustate[px];
        med_i = ustate[plane + px];
        if (last_span) {
            T = Tf;
            S = Tf * bg_dot;
        } else {
            T = bstate[px];
            S = bstate[plane + px];
        }
    }
    float A = 1.0 - Tf;

    // No pixel of the tile blended anything past its last contributor:
    // start from the largest one (the forward usually stops well before the
    // end of the list).
    uint sg_last = subgroupMax(last);
    if (subgroupElect()) {
        s_last[gl_SubgroupID] = sg_last;
    }
    barrier();
    uint tile_last = 0u;
    for (uint s = 0u; s < gl_NumSubgroups; s++) {
        tile_last = max(tile_last, s_last[s]);
    }
    uint full_end = end;
    end = min(end, max(tile_last, start));
    // The skipped intersections still own their slots: zero them.
    for (uint q = end + lid; q < full_end; q += WG) {
        uint b = vals[q] * KREC;
        for (uint k = 0u; k < KREC; k++) {
            RECORDS[b + k] = 0.0;
        }
    }

    uint bend = end;
    while (bend > start) {
        uint bstart = bend - start > BATCH ? bend - BATCH : start;
        for (uint j = 0u; j < BATCH; j++) {
            bool valid = j < bend - bstart;
            uint q = valid ? bend - 1u - j : bstart;
            uint g = gid[vals[q]];
            uint o = PROJ_STRIDE * g;
            vec3 tu = vec3(proj[o], proj[o + 1u], proj[o + 2u]);
            vec3 tv = vec3(proj[o + 3u], proj[o + 4u], proj[o + 5u]);
            vec3 tw = vec3(proj[o + 6u], proj[o + 7u], proj[o + 8u]);
            vec2 mu = vec2(proj[o + 9u], proj[o + 10u]);
            vec3 nrm = vec3(proj[o + 11u], proj[o + 12u], proj[o + 13u]);
            float op = proj[o + 14u];
            vec4 box = vec4(proj[o + 16u], proj[o + 17u], proj[o + 18u], proj[o + 19u]);

            Hit h;
            bool contrib = valid && inside && q < last && in_box(box, pf) && intersect(tu, tv, tw, mu, pf, h);
            float alpha = contrib ? min(ALPHA_MAX, op * h.g) : 0.0;
            contrib = contrib && alpha >= ALPHA_MIN;

            vec3 dTu = vec3(0.0), dTv = vec3(0.0), dTw = vec3(0.0), dn = vec3(0.0);
            vec2 dmu = vec2(0.0);
            float dO = 0.0, w = 0.0;
#ifdef COLOUR_ONLY
            if (contrib) {
                float Ti = T / (1.0 - alpha);
                w = alpha * Ti;
                T = Ti;
            }
#else
            if (contrib) {
                float m = ndc_depth(h.z);
                float V = gA + gD * h.z + dot(gN, nrm) + gDist * (m * m * A + M2 - 2.0 * m * M1);
                for (uint c = 0u; c < CH; c++) {
                    V += gC[c] * pfeat[g * CH + c];
                }
                PixelRec r = pixel_grad(h, alpha, op, tw, mu, pf, V, m, gD, gDist, gMed, gN, A, M1, q == med_i, T, S);
                dTu = r.dTu;
                dTv = r.dTv;
                dTw = r.dTw;
                dmu = r.dmu;
                dO = r.dO;
                dn = r.dn;
                w = r.w;
            }
#endif
            // Sum over the subgroup; one partial per subgroup and splat.
            uint base = (gl_SubgroupID * BATCH + j) * KREC;
            if (subgroupAny(contrib)) {
#ifndef COLOUR_ONLY
                dTu = subgroupAdd(dTu);
                dTv = subgroupAdd(dTv);
                dTw = subgroupAdd(dTw);
                dmu = subgroupAdd(dmu);
                dO = subgroupAdd(dO);
                dn = subgroupAdd(dn);
#endif
                for (uint c = 0u; c < CH; c++) {
                    float v = subgroupAdd(w * gC[c]);
                    if (subgroupElect()) {
                        part[base + 15u + c] = v;
                    }
                }
            } else if (subgroupElect()) {
                for (uint c = 0u; c < CH; c++) {
                    part[base + 15u + c] = 0.0;
                }
            }
            if (subgroupElect()) {
                part[base + 0u] = dTu.x; part[base + 1u] = dTu.y; part[base + 2u] = dTu.z;
                part[base + 3u] = dTv.x; part[base + 4u] = dTv.y; part[base + 5u] = dTv.z;
                part[base + 6u] = dTw.x; part[base + 7u] = dTw.y; part[base + 8u] = dTw.z;
                part[base + 9u] = dmu.x; part[base + 10u] = dmu.y;
                part[base + 11u] = dO;
                part[base + 12u] = dn.x; part[base + 13u] = dn.y; part[base + 14u] = dn.z;
            }
        }
        barrier();
        // Sum the subgroup partials in subgroup order into each splat's slot.
        uint nb = bend - bstart;
        for (uint v = lid; v < nb * KREC; v += WG) {
            uint j = v / KREC, k = v % KREC;
            float sum = 0.0;
            for (uint s = 0u; s < gl_NumSubgroups; s++) {
                sum += part[(s * BATCH + j) * KREC + k];
            }
            RECORDS[vals[bend - 1u - j] * KREC + k] = sum;
        }
        barrier();
        bend = bstart;
    }
    if (inside) {
        bstate[px] = T;
        bstate[plane + px] = S;
    }
}
