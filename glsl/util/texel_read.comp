#version 460
// out[i] = bits(f[i]) ^ u[i] for i < count, f and u read as uniform texel
// buffers (tests/tests/engine.rs: the engine's texel-buffer bindings).
#include "common.glsl"

layout(binding = 0) uniform samplerBuffer f_t;
layout(binding = 1) uniform usamplerBuffer u_t;
layout(std430, binding = 2) writeonly buffer Out { uint out_[]; };
layout(push_constant) uniform Push { uint count; } pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i < pc.count) {
        out_[i] = floatBitsToUint(texelFetch(f_t, int(i)).r) ^ texelFetch(u_t, int(i)).r;
    }
}
