#version 460
// Sum of the weight gradients' per-chunk partials in a fixed order:
// grad[i] = sum over z < chunks of part[z stride + i], z increasing; with
// accumulate != 0 that sum is added to grad[i] (the samples' later blocks:
// pipelines/src/mlp `Block`). With
// counted != 0 the chunks are those of min(count[0], counted) samples
// (mlp/chunks.glsl), a count a kernel of the same recording wrote.
#include "common.glsl"
#include "mlp/chunks.glsl"

layout(std430, binding = 0) readonly buffer Part { float part[]; };
layout(std430, binding = 1) buffer Grad { float grad[]; };
layout(std430, binding = 2) readonly buffer Count { uint count[]; };
layout(push_constant) uniform Push {
    uint n;
    uint chunks;
    uint stride;
    uint counted;
    uint accumulate;
} pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    uint chunks = pc.counted != 0u ? weight_chunk_count(min(count[0], pc.counted)) : pc.chunks;
    float s = 0.0;
    for (uint z = 0u; z < chunks; z++) {
        s += part[z * pc.stride + i];
    }
    grad[i] = pc.accumulate != 0u ? grad[i] + s : s;
}
