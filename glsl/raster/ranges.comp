#version 460
// [start, end) of every tile in the tile-sorted intersection list (ranges
// must be zeroed first; empty tiles keep [0, 0)).
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Params { uint params[]; };
layout(std430, binding = 1) readonly buffer Keys { uint keys[]; };
layout(std430, binding = 2) writeonly buffer Ranges { uvec2 ranges[]; };

void main() {
    uint q = wg_linear() * WG + gl_LocalInvocationID.x;
    uint m = params[0];
    if (q >= m) {
        return;
    }
    uint t = keys[q];
    if (q == 0u || keys[q - 1u] != t) {
        ranges[t].x = q;
    }
    if (q + 1u == m || keys[q + 1u] != t) {
        ranges[t].y = q + 1u;
    }
}
