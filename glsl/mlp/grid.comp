#version 460
// The workgroups of one counted dispatch of the light field (pipelines/src/mlp
// `Mlp::record_grid`), written as its indirect dispatch arguments: enough
// for min(capacity, rows[0]) items at per_group items a workgroup, the count
// a kernel of the same recording wrote. So the work follows the count without
// the host reading it back, and no workgroup past it is launched: on
// llvmpipe a launched workgroup costs even when it returns at once (the
// viewer's forward of Φ on 31k of 120k pixels: 105 ms over the capacity's
// grid, 67 ms over the count's; perf/journal, seventieth entry).
#include "util/groups_2d.glsl"
layout(local_size_x = 1) in;

layout(std430, binding = 0) readonly buffer Rows { uint rows[]; };
layout(std430, binding = 1) writeonly buffer Args { uint args[]; };
layout(push_constant) uniform Push {
    uint capacity;
    uint per_group;
    // The groups along y, with x and z given; x = 0: laid out by groups_2d.
    uint x;
    uint z;
    uint max_x;
} pc;

void main() {
    uint groups = (min(pc.capacity, rows[0]) + pc.per_group - 1u) / pc.per_group;
    uvec3 g = pc.x == 0u ? groups_2d(groups, pc.max_x) : uvec3(pc.x, groups, pc.z);
    args[0] = g.x;
    args[1] = g.y;
    args[2] = g.z;
}
