#version 460
// Radix sort, down-sweep: stable rank of each key within its partition and
// scatter to its global position (scanned histogram + rank).
//
// Subgroup s owns the contiguous keys [s*SG*KPT, (s+1)*SG*KPT) of the
// partition and walks them in order (k, lane), so ranks follow input order:
//  1. per key, lanes holding the same digit are found with RADIX_BITS ballots;
//     the rank is the running count of that digit in the subgroup
//     (sub[s][d], private to the subgroup: no workgroup barrier in the loop)
//     plus the number of matching lower lanes;
//  2. per digit, the subgroup counts are scanned across subgroups, and the
//     digit totals across digits (local offsets);
//  3. keys, then values, are reordered through shared memory so the global
//     writes are contiguous runs per digit.
// Works for any subgroup size from MIN_SG to 128; shared arrays are sized
// by specialization constants.
#include "sort_common.glsl"
#include "wg_scan.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer KeysIn { uint keys_in[]; };
layout(std430, binding = 2) readonly buffer ValsIn { uint vals_in[]; };
layout(std430, binding = 3) readonly buffer Hist { uint hist[]; };
layout(std430, binding = 4) writeonly buffer KeysOut { uint keys_out[]; };
layout(std430, binding = 5) writeonly buffer ValsOut { uint vals_out[]; };

shared uint sub[MAX_SG * RADIX];
shared uint local_off[RADIX];
shared uint global_off[RADIX];
shared uint sbuf[gl_WorkGroupSize.x * KPT];

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

    for (uint i = t; i < gl_NumSubgroups * RADIX; i += WG) {
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
        uint prior = valid ? sub[s * RADIX + d] : 0u;
        subgroupBarrier();
        if (valid && below == same - 1u) {
            sub[s * RADIX + d] = prior + same;
        }
        subgroupMemoryBarrierShared();
        subgroupBarrier();
        key[k] = kv;
        pos[k] = valid ? prior + below : 0xffffffffu;
    }
    barrier();

    // Per digit: exclusive scan of the subgroup counts across subgroups.
    uint total = 0u;
    if (t < RADIX) {
        for (uint j = 0; j < gl_NumSubgroups; j++) {
            uint c = sub[j * RADIX + t];
            sub[j * RADIX + t] = total;
            total += c;
        }
    }
    uint all;
    uint excl = wg_exclusive_scan(t < RADIX ? total : 0u, all);
    if (t < RADIX) {
        local_off[t] = excl;
        global_off[t] = hist[t * parts + p] - excl;
    }
    barrier();

    for (uint k = 0; k < KPT; k++) {
        if (pos[k] != 0xffffffffu) {
            uint d = digit_of(key[k]);
            pos[k] += local_off[d] + sub[s * RADIX + d];
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
