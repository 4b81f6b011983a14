#version 460
// Scan, level reduce: sums[b] = sum of block b (WG * KPT elements) of `data`.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer Data { uint data[]; };
layout(std430, binding = 2) writeonly buffer Sums { uint sums[]; };

layout(push_constant) uniform Push { uint len_slot; } pc;

shared uint part[MAX_SG];

void main() {
    uint n = params[pc.len_slot];
    uint b = wg_linear();
    uint B = WG * KPT;
    if (b * B >= n) {
        return;  // whole workgroup: uniform
    }
    uint t = gl_LocalInvocationID.x;
    uint s = 0;
    for (uint k = 0; k < KPT; k++) {
        uint i = b * B + k * WG + t;
        if (i < n) {
            s += data[i];
        }
    }
    s = subgroupAdd(s);
    if (subgroupElect()) {
        part[gl_SubgroupID] = s;
    }
    barrier();
    if (t == 0) {
        uint total = 0;
        for (uint i = 0; i < gl_NumSubgroups; i++) {
            total += part[i];
        }
        sums[b] = total;
    }
}
