// Workgroup-wide exclusive prefix sum of one uint per invocation, for any
// subgroup size from MIN_SG up (4..128). Three barriers; every invocation of
// the workgroup must call it (uniform control flow).
#ifndef TGS_WG_SCAN_GLSL
#define TGS_WG_SCAN_GLSL
#include "common.glsl"

shared uint wgs_part[MAX_SG];
shared uint wgs_total;

uint wg_exclusive_scan(uint v, out uint total) {
    uint incl = subgroupInclusiveAdd(v);
    uint sg_sum = subgroupAdd(v);
    if (subgroupElect()) {
        wgs_part[gl_SubgroupID] = sg_sum;
    }
    barrier();
    if (gl_SubgroupID == 0) {
        // Scan the per-subgroup sums with the first subgroup, in chunks.
        uint carry = 0;
        for (uint base = 0; base < gl_NumSubgroups; base += gl_SubgroupSize) {
            uint i = base + gl_SubgroupInvocationID;
            uint x = i < gl_NumSubgroups ? wgs_part[i] : 0u;
            uint xi = subgroupInclusiveAdd(x);
            if (i < gl_NumSubgroups) {
                wgs_part[i] = carry + xi - x;
            }
            carry += subgroupAdd(x);
        }
        if (subgroupElect()) {
            wgs_total = carry;
        }
    }
    barrier();
    total = wgs_total;
    uint r = wgs_part[gl_SubgroupID] + incl - v;
    barrier();
    return r;
}

#endif
