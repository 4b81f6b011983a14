#version 460
// data[i] = start + i for i < count (a window of a buffer, 2-D grid).
#include "common.glsl"

layout(std430, binding = 0) writeonly buffer Data { uint data[]; };
layout(push_constant) uniform Push { uint count; uint start; } pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i < pc.count) {
        data[i] = pc.start + i;
    }
}
