#version 460
// One invocation: reads the element count from a GPU buffer and writes the
// per-level lengths and indirect dispatch arguments for a scan or a radix
// sort, so callers never read counts back to the host.
//
// params[0] = n (clamped to capacity), params[1] = partitions (sort),
// params[2 + l] = length of scan level l; params[2 + levels] = the count as
// read, before clamping (so callers can detect a count over capacity).
// args[4*0 ..] = partition grid (sort); args[4*(1+l) ..] = grid of scan level l.
#include "util/groups_2d.glsl"
layout(local_size_x = 1) in;

layout(std430, binding = 0) readonly buffer Count { uint count[]; };
layout(std430, binding = 1) writeonly buffer Params { uint params[]; };
layout(std430, binding = 2) writeonly buffer Args { uint args[]; };

layout(push_constant) uniform Push {
    uint count_index;  // element of `count` holding n
    uint mode;         // 0: scan of n elements; 1: sort spine of radix * partitions
    uint part_size;    // sort partition size
    uint radix;        // sort digit count
    uint block;        // scan block size
    uint levels;       // number of scan levels (>= 1)
    uint max_x;        // per-dimension workgroup limit
    uint capacity;     // n is clamped to this
} pc;

void grid(uint slot, uint groups) {
    uvec3 g = groups_2d(groups, pc.max_x);
    args[4u * slot + 0u] = g.x;
    args[4u * slot + 1u] = g.y;
    args[4u * slot + 2u] = g.z;
    args[4u * slot + 3u] = 0u;
}

void main() {
    uint requested = count[pc.count_index];
    uint n = min(requested, pc.capacity);
    params[2u + pc.levels] = requested;
    uint parts = pc.mode == 1u ? (n + pc.part_size - 1u) / pc.part_size : 0u;
    params[0] = n;
    params[1] = parts;
    grid(0u, parts);
    uint len = pc.mode == 1u ? parts * pc.radix : n;
    for (uint l = 0u; l < pc.levels; l++) {
        params[2u + l] = len;
        uint groups = (len + pc.block - 1u) / pc.block;
        grid(1u + l, groups);
        len = groups;
    }
}
