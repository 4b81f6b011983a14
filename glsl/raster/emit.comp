#version 460
// One invocation per depth-ranked Gaussian r: emits its intersections at
// [offsets[r], offsets[r + 1]) (so a Gaussian's intersections are contiguous
// and in depth order overall): tile key, emission index, Gaussian id.
// Intersections past the capacity are dropped (the plan records the total).
#include "common.glsl"
#include "raster/common.glsl"

layout(std430, binding = 0) readonly buffer Ids { uint ids[]; };
layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) readonly buffer Rects { uvec4 rects[]; };
layout(std430, binding = 3) writeonly buffer Keys { uint keys[]; };
layout(std430, binding = 4) writeonly buffer Vals { uint vals[]; };
layout(std430, binding = 5) writeonly buffer Gid { uint gid[]; };

void main() {
    uint r = wg_linear() * WG + gl_LocalInvocationID.x;
    if (r >= pc.n) {
        return;
    }
    uint g = ids[r];
    uint p = offsets[r];
    uint end = min(offsets[r + 1u], pc.capacity);
    if (p >= end) {
        return;
    }
    uvec4 rc = rects[g];
    for (uint ty = rc.y; ty < rc.w && p < end; ty++) {
        for (uint tx = rc.x; tx < rc.z && p < end; tx++) {
            keys[p] = ty * pc.tiles_x + tx;
            vals[p] = p;
            gid[p] = g;
            p++;
        }
    }
}
