#version 460
// counts[r] = tiles[ids[r]] for the depth-sorted order; counts[n] = 0 so the
// exclusive scan's last element is the total number of intersections.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Ids { uint ids[]; };
layout(std430, binding = 1) readonly buffer Tiles { uint tiles[]; };
layout(std430, binding = 2) writeonly buffer Counts { uint counts[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint r = wg_linear() * WG + gl_LocalInvocationID.x;
    if (r < pc.n) {
        counts[r] = tiles[ids[r]];
    } else if (r == pc.n) {
        counts[r] = 0u;
    }
}
