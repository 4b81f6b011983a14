#version 460
// variant: RECORDS_BDA
// variant: COLOUR_ONLY
// variant: COLOUR_ONLY RECORDS_BDA
#ifdef RECORDS_BDA
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#endif
// Per-pixel 2DGS backward in ONE SUBGROUP per tile (for CPU drivers, where
// a workgroup's subgroups run as coroutines on one thread and barriers and
// shared-memory traffic dominate). The workgroup is one subgroup of WG
// invocations; invocation l owns the PPT = TILE^2 / WG pixels l, l + WG, ...
// of the tile (8x8 where the frame allows, else 16x16) and keeps their
// state in registers. Back to front, for each splat every invocation sums
// the gradient records of its pixels inside the splat's pixel box (only
// the rows the box reaches: `box_slots`, skipped in a loop of constant
// length so that the state stays in registers) in pixel order,
// one subgroupAdd per record entry sums the invocations, and one invocation
// writes the intersection's own slot: no shared memory, no barriers, no
// atomics, one writer per slot in a fixed order (bit-identical run to run).
// The math per pixel is raster/backward.comp's (method-notes §1.7); spans
// are processed last to first with (T, S) carried in `bstate`.
// COLOUR_ONLY: the feature gradients alone (a set whose geometry does not
// train): per pixel the weight w = alpha T_i and the feature sums, the
// same operations as the full kernel's, so those records are bit-identical
// to its; the geometric entries are zero and S is not carried.
#include "common.glsl"
#include "raster/common.glsl"
#include "raster/pixel_grad.glsl"

layout(constant_id = 6) const uint PPT = 32;  // pixels per invocation; WG * PPT = TILE * TILE

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
// The tile's splats as uniform texel buffers: llvmpipe fetches a texel as
// one gather, where it loads from a storage buffer lane by lane with a
// branch and a spill each (the light field's GEMM, perf/RESULTS.md,
// forty-first entry). Every invocation reads the same splat.
layout(binding = 2) uniform usamplerBuffer vals_t;
layout(binding = 3) uniform usamplerBuffer gid_t;
layout(binding = 4) uniform samplerBuffer proj_t;
layout(binding = 5) uniform samplerBuffer pfeat_t;
#define VALS(at) texelFetch(vals_t, int(at)).r
#define GID(at) texelFetch(gid_t, int(at)).r
#define PROJ(at) texelFetch(proj_t, int(at)).r
#define PFEAT(at) texelFetch(pfeat_t, int(at)).r
layout(std430, binding = 6) readonly buffer Out { float outp[]; };
layout(std430, binding = 7) readonly buffer FState { float fstate[]; };
layout(std430, binding = 8) readonly buffer UState { uint ustate[]; };
layout(std430, binding = 9) readonly buffer GradOut { float gout[]; };
layout(std430, binding = 10) buffer BState { float bstate[]; };
#define RECORDS_BINDING 11
#define RECORDS_ACCESS writeonly
#include "raster/records.glsl"

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
    uint plane = pc.width * pc.height;

    // Per-pixel upstream gradients and forward state.
    vec2 pfs[PPT];
    bool ins[PPT];
    uint pxs[PPT], lasts[PPT], meds[PPT];
    float gCs[PPT * CH];
    float gAs[PPT], gDs[PPT], gMeds[PPT], gDists[PPT], As[PPT], M1s[PPT], M2s[PPT], Ts[PPT], Ss[PPT];
    vec3 gNs[PPT];
    uint my_last = 0u;
    for (uint k = 0u; k < PPT; k++) {
        uint i = lid + k * WG;
        uvec2 pix = uvec2(tx * TILE + (i % TILE), ty * TILE + (i / TILE));
        bool inside = pix.x < pc.width && pix.y < pc.height;
        uint px = inside ? pix.y * pc.width + pix.x : 0u;
        pfs[k] = vec2(pix);
        ins[k] = inside;
        pxs[k] = px;
        float bg_dot = 0.0;
        for (uint c = 0u; c < CH; c++) {
            float g = inside ? gout[c * plane + px] : 0.0;
            gCs[k * CH + c] = g;
            bg_dot += g * cam[20u + c];
        }
        float Tf = inside ? fstate[px] : 1.0;
        gAs[k] = inside ? gout[P_ALPHA * plane + px] : 0.0;
        gDs[k] = inside ? gout[P_DEPTH * plane + px] : 0.0;
        gNs[k] = inside ? vec3(gout[P_NORMAL * plane + px], gout[(P_NORMAL + 1u) * plane + px], gout[(P_NORMAL + 2u) * plane + px]) : vec3(0.0);
        gMeds[k] = inside ? gout[P_MEDIAN * plane + px] : 0.0;
        gDists[k] = inside ? gout[P_DIST * plane + px] : 0.0;
        M1s[k] = inside ? fstate[plane + px] : 0.0;
        M2s[k] = inside ? fstate[2u * plane + px] : 0.0;
        lasts[k] = inside ? ustate[px] : 0u;
        meds[k] = inside ? ustate[plane + px] : 0xFFFFFFFFu;
        As[k] = 1.0 - Tf;
        Ts[k] = !inside ? 1.0 : (last_span ? Tf : bstate[px]);
        Ss[k] = !inside ? 0.0 : (last_span ? Tf * bg_dot : bstate[plane + px]);
        my_last = max(my_last, lasts[k]);
    }

    // No pixel of the tile blended anything past its last contributor.
    uint tile_last = subgroupMax(my_last);
    uint full_end = end;
    end = min(end, max(tile_last, start));
    // The skipped intersections still own their slots: zero them.
    for (uint q = end + lid; q < full_end; q += WG) {
        uint b = VALS(q) * KREC;
        for (uint r = 0u; r < KREC; r++) {
            RECORDS[b + r] = 0.0;
        }
    }

    float feat[CH], dF[CH];
    for (uint q1 = end; q1 > start; q1--) {
        uint q = q1 - 1u;
        uint g = GID(VALS(q));
        uint o = PROJ_STRIDE * g;
        vec3 tu = vec3(PROJ(o), PROJ(o + 1u), PROJ(o + 2u));
        vec3 tv = vec3(PROJ(o + 3u), PROJ(o + 4u), PROJ(o + 5u));
        vec3 tw = vec3(PROJ(o + 6u), PROJ(o + 7u), PROJ(o + 8u));
        vec2 mu = vec2(PROJ(o + 9u), PROJ(o + 10u));
        vec3 nrm = vec3(PROJ(o + 11u), PROJ(o + 12u), PROJ(o + 13u));
        float op = PROJ(o + 14u);
        vec4 box = vec4(PROJ(o + 16u), PROJ(o + 17u), PROJ(o + 18u), PROJ(o + 19u));
        for (uint c = 0u; c < CH; c++) {
            feat[c] = PFEAT(g * CH + c);
            dF[c] = 0.0;
        }
        vec3 dTu = vec3(0.0), dTv = vec3(0.0), dTw = vec3(0.0), dn = vec3(0.0);
        vec2 dmu = vec2(0.0);
        float dO = 0.0;
        // Only the pixels of the splat's box (the forward's): the rows it
        // reaches, skipped inside a loop of constant length. Unrolled, that
        // loop indexes the pixel state with constants, which llvmpipe keeps
        // in registers; a loop from ks.x to ks.y indexed it at run time,
        // spilled it, and took a quarter more time (perf/RESULTS.md,
        // forty-ninth entry).
        uvec2 ks = box_slots(box, ty, PPT);
        for (uint k = 0u; k < PPT; k++) {
            if (k < ks.x || k >= ks.y) {
                continue;
            }
            Hit h;
            vec2 pf = pfs[k];
            if (!in_box(box, pf)) {
                continue;
            }
            bool contrib = ins[k] && q < lasts[k] && intersect(tu, tv, tw, mu, pf, h);
            float alpha = contrib ? min(ALPHA_MAX, op * h.g) : 0.0;
            if (!(contrib && alpha >= ALPHA_MIN)) {
                continue;
            }
#ifdef COLOUR_ONLY
            float Ti = Ts[k] / (1.0 - alpha);
            float w = alpha * Ti;
            Ts[k] = Ti;
            for (uint c = 0u; c < CH; c++) {
                dF[c] += w * gCs[k * CH + c];
            }
#else
            float m = ndc_depth(h.z);
            float V = gAs[k] + gDs[k] * h.z + dot(gNs[k], nrm) + gDists[k] * (m * m * As[k] + M2s[k] - 2.0 * m * M1s[k]);
            for (uint c = 0u; c < CH; c++) {
                V += gCs[k * CH + c] * feat[c];
            }
            PixelRec r = pixel_grad(h, alpha, op, tw, mu, pf, V, m, gDs[k], gDists[k], gMeds[k], gNs[k], As[k], M1s[k], q == meds[k], Ts[k], Ss[k]);
            for (uint c = 0u; c < CH; c++) {
                dF[c] += r.w * gCs[k * CH + c];
            }
            dTu += r.dTu;
            dTv += r.dTv;
            dTw += r.dTw;
            dmu += r.dmu;
            dO += r.dO;
            dn += r.dn;
#endif
        }
        // One subgroup is the whole tile: its sum is the splat's gradient.
#ifndef COLOUR_ONLY
        dTu = subgroupAdd(dTu);
        dTv = subgroupAdd(dTv);
        dTw = subgroupAdd(dTw);
        dmu = subgroupAdd(dmu);
        dO = subgroupAdd(dO);
        dn = subgroupAdd(dn);
#endif
        for (uint c = 0u; c < CH; c++) {
            dF[c] = subgroupAdd(dF[c]);
        }
        if (subgroupElect()) {
            uint b = VALS(q) * KREC;
            RECORDS[b + 0u] = dTu.x; RECORDS[b + 1u] = dTu.y; RECORDS[b + 2u] = dTu.z;
            RECORDS[b + 3u] = dTv.x; RECORDS[b + 4u] = dTv.y; RECORDS[b + 5u] = dTv.z;
            RECORDS[b + 6u] = dTw.x; RECORDS[b + 7u] = dTw.y; RECORDS[b + 8u] = dTw.z;
            RECORDS[b + 9u] = dmu.x; RECORDS[b + 10u] = dmu.y;
            RECORDS[b + 11u] = dO;
            RECORDS[b + 12u] = dn.x; RECORDS[b + 13u] = dn.y; RECORDS[b + 14u] = dn.z;
            for (uint c = 0u; c < CH; c++) {
                RECORDS[b + 15u + c] = dF[c];
            }
        }
    }
    for (uint k = 0u; k < PPT; k++) {
        if (ins[k]) {
            bstate[pxs[k]] = Ts[k];
            bstate[plane + pxs[k]] = Ss[k];
        }
    }
}
