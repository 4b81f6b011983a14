#version 460
// One invocation, recorded after a view's forward (and anything that reads
// it) in the same submission as the updates that follow: indirect dispatch
// arguments for up to 8 later dispatches (Adam per array, densification
// statistics), each the host's grid when the view fitted its frame and zero
// groups when it did not (more intersections than the frame holds, or a
// tile needing more span passes than were recorded). An overflowed view thus
// changes no parameter, moment or statistic; the host grows the frame and
// runs the iteration again.
layout(local_size_x = 1) in;

layout(std430, binding = 0) readonly buffer Stats { uint stats[]; };  // [total, span overflow]
layout(std430, binding = 1) writeonly buffer Args { uint args[]; };
layout(push_constant) uniform Push {
    uint capacity;
    uint count;
    uint pad0;
    uint pad1;
    uint grids[24];  // x, y, z of grid k at 3k (push constants are std430); 3 x GATE_SLOTS (pipelines/src/raster/mod.rs, checked by a test)
} pc;

void main() {
    bool fits = stats[0] <= pc.capacity && stats[1] == 0u;
    for (uint k = 0u; k < pc.count; ++k) {
        for (uint d = 0u; d < 3u; ++d) {
            args[3u * k + d] = fits ? pc.grids[3u * k + d] : 0u;
        }
    }
}
