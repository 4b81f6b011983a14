#version 460
// One invocation: the intersection total (the scan's last element), clamped
// to the capacity, and the indirect grid for one invocation per intersection.
// stats[0] = total as counted, stats[1] = span overflow flag (reset here).
#include "util/groups_2d.glsl"
layout(local_size_x = 1) in;

layout(std430, binding = 0) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 1) writeonly buffer Params { uint params[]; };
layout(std430, binding = 2) writeonly buffer Args { uint args[]; };
layout(std430, binding = 3) writeonly buffer Stats { uint stats[]; };
layout(push_constant) uniform Push { uint n; uint capacity; uint wg; uint max_x; } pc;

void main() {
    uint total = offsets[pc.n];
    uint m = min(total, pc.capacity);
    params[0] = m;
    stats[0] = total;
    stats[1] = 0u;
    uint groups = (m + pc.wg - 1u) / pc.wg;
    uvec3 g = groups_2d(groups, pc.max_x);
    args[0] = g.x;
    args[1] = g.y;
    args[2] = g.z;
}
