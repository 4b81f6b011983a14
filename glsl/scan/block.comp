#version 460
// Scan, level down-sweep: exclusive prefix sum within each block of WG * KPT
// elements, plus the block's offset from the scanned level above (if any).
// `src` and `dst` may be the same buffer.
#include "scan/wg_scan.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer Src { uint src[]; };
layout(std430, binding = 2) writeonly buffer Dst { uint dst[]; };
layout(std430, binding = 3) readonly buffer Offsets { uint offsets[]; };

layout(push_constant) uniform Push { uint len_slot; uint has_offsets; } pc;

shared uint sdata[gl_WorkGroupSize.x * KPT];

void main() {
    uint n = params[pc.len_slot];
    uint b = wg_linear();
    uint B = WG * KPT;
    if (b * B >= n) {
        return;
    }
    uint t = gl_LocalInvocationID.x;
    uint base = b * B;
    for (uint k = 0; k < KPT; k++) {
        uint i = k * WG + t;
        sdata[i] = base + i < n ? src[base + i] : 0u;
    }
    barrier();
    uint run = 0;
    for (uint k = 0; k < KPT; k++) {
        uint x = sdata[t * KPT + k];
        sdata[t * KPT + k] = run;
        run += x;
    }
    uint total;
    uint off = wg_exclusive_scan(run, total);
    if (pc.has_offsets != 0u) {
        off += offsets[b];
    }
    for (uint k = 0; k < KPT; k++) {
        sdata[t * KPT + k] += off;
    }
    barrier();
    for (uint k = 0; k < KPT; k++) {
        uint i = k * WG + t;
        if (base + i < n) {
            dst[base + i] = sdata[i];
        }
    }
}
