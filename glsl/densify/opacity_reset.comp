#version 460
// Opacity reset (method-notes §1.11): raw opacity <- min(raw, logit(cap)),
// and the Adam moments of the opacity are zeroed.
#include "common.glsl"

layout(std430, binding = 0) buffer Opac { float opacity[]; };
layout(std430, binding = 1) buffer M { float m1[]; };
layout(std430, binding = 2) buffer V { float m2[]; };
layout(push_constant) uniform Push { uint n; float raw_cap; } pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    opacity[i] = min(opacity[i], pc.raw_cap);
    m1[i] = 0.0;
    m2[i] = 0.0;
}
