#version 460
// Radix sort, down-sweep: stable rank of each key within its partition and
// scatter to its global position (scanned histogram + rank).
//
// Subgroup s owns the contiguous keys [s*SG*KPT, (s+1)*SG*KPT) of the
// partition and walks them in order (k, lane), so ranks follow input order:
//  1. per key, lanes holding the same digit are found with RADIX_BITS ballots;
//     the highest such lane adds their number to the subgroup's running count
//     of that digit (a shared integer atomic, so the two digits sharing a
//     packed word never race; counts are exact, hence deterministic) and
//     shuffles the old count to the others; rank = old count + lower lanes;
//  2. per digit, the subgroup counts are scanned across subgroups, and the
//     digit totals across digits (local offsets);
//  3. keys, then values, are reordered through shared memory so the global
//     writes are contiguous runs per digit.
// Subgroup counts are u16 pairs (a partition holds < 65,536 keys), which
// halves shared memory: 8-bit digits fit lavapipe's 32 KiB. Works for any
// subgroup size from MIN_SG to 128; arrays are sized by specialization
// constants.
#include "sort/common.glsl"
#include "scan/wg_scan.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer KeysIn { uint keys_in[]; };
layout(std430, binding = 2) readonly buffer ValsIn { uint vals_in[]; };
layout(std430, binding = 3) readonly buffer Hist { uint hist[]; };
layout(std430, binding = 4) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 5) writeonly buffer ValsOut { uint vals_out[]; };

#extension GL_KHR_shader_subgroup_shuffle : require

#define RADIX2 (RADIX / 2u)
shared uint sub[MAX_SG * RADIX2];   // [subgroup][digit pair]: two u16 counts
shared uint local_off[RADIX];
shared uint global_off[RADIX];
shared uint sbuf[gl_WorkGroupSize.x * KPT];

uint sub_count(uint s, uint d) {
    return (sub[s * RADIX2 + (d >> 1)] >> ((d & 1u) * 16u)) & 0xffffu;
}

void main() {
    uint n = params[0];
    uint parts = params[1];
    uint p = wg_linear();
    if (p >= parts) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint P = WG * KPT;
    uint part_base = p * P;
    uint part_n = min(P, n - part_base);

    for (uint i = t; i < gl_NumSubgroups * RADIX2; i += WG) {
        sub[i] = 0u;
    }
    barrier();

    uint s = gl_SubgroupID;
    uint lane = gl_SubgroupInvocationID;
    uint SG = gl_SubgroupSize;
    uint sub_base = s * SG * KPT;

    uint key[KPT];
    uint pos[KPT];
    for (uint k = 0; k < KPT; k++) {
        uint li = sub_base + k * SG + lane;
        bool valid = li < part_n;
        uint kv = valid ? keys_in[part_base + li] : 0u;
        uint d = digit_of(kv);
        uvec4 match = subgroupBallot(valid);
        for (uint b = 0; b < RADIX_BITS; b++) {
            bool bit = ((d >> b) & 1u) != 0u;
            uvec4 ones = subgroupBallot(bit);
            match &= bit ? ones : ~ones;
        }
        uint below = subgroupBallotExclusiveBitCount(match);
        uint same = subgroupBallotBitCount(match);
        uint leader = valid ? subgroupBallotFindMSB(match) : lane;
        uint sh = (d & 1u) * 16u;
        uint old = 0u;
        if (valid && lane == leader) {
            old = atomicAdd(sub[s * RADIX2 + (d >> 1)], same << sh);
        }
        uint prior = (subgroupShuffle(old, leader) >> sh) & 0xffffu;
        key[k] = kv;
        pos[k] = valid ? prior + below : 0xffffffffu;
    }
    barrier();

    // Per digit pair: exclusive scan of the subgroup counts across subgroups.
    uint tot_lo = 0u, tot_hi = 0u;
    if (t < RADIX2) {
        for (uint j = 0; j < gl_NumSubgroups; j++) {
            uint w = sub[j * RADIX2 + t];
            sub[j * RADIX2 + t] = tot_lo | (tot_hi << 16);
            tot_lo += w & 0xffffu;
            tot_hi += w >> 16;
        }
    }
    uint all;
    uint excl = wg_exclusive_scan(t < RADIX2 ? tot_lo + tot_hi : 0u, all);
    if (t < RADIX2) {
        local_off[2u * t] = excl;
        local_off[2u * t + 1u] = excl + tot_lo;
    }
    barrier();
    for (uint d = t; d < RADIX; d += WG) {
        global_off[d] = hist[d * parts + p] - local_off[d];
    }
    barrier();

    for (uint k = 0; k < KPT; k++) {
        if (pos[k] != 0xffffffffu) {
            uint d = digit_of(key[k]);
            pos[k] += local_off[d] + sub_count(s, d);
            sbuf[pos[k]] = key[k];
        }
    }
    barrier();
    uint dig[KPT];
    for (uint k = 0; k < KPT; k++) {
        uint i = k * WG + t;
        if (i < part_n) {
            uint kv = sbuf[i];
            uint d = digit_of(kv);
            dig[k] = d;
            keys_out[global_off[d] + i] = kv;
        }
    }
    barrier();
    for (uint k = 0; k < KPT; k++) {
        if (pos[k] != 0xffffffffu) {
            sbuf[pos[k]] = vals_in[part_base + sub_base + k * SG + lane];
        }
    }
    barrier();
    for (uint k = 0; k < KPT; k++) {
        uint i = k * WG + t;
        if (i < part_n) {
            vals_out[global_off[dig[k]] + i] = sbuf[i];
        }
    }
}
