#version 460
// data[first + i] = first + i through a buffer device address, so buffers
// larger than maxStorageBufferRange (128 MiB on lavapipe) are reachable.
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#include "common.glsl"

layout(buffer_reference, std430, buffer_reference_align = 4) buffer Words { uint w[]; };
layout(push_constant) uniform Push { uvec2 addr; uint first; uint count; } pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i < pc.count) {
        Words b = Words(pc.addr);
        b.w[pc.first + i] = pc.first + i;
    }
}
