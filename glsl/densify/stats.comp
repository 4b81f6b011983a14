#version 460
// Densification statistics after a backward (method-notes §1.11): for each
// Gaussian seen in the view (radius > 0) accumulate the norm of its
// screen-space gradient and count the view; keep the largest screen radius.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Densify { vec2 densify[]; };
layout(std430, binding = 1) readonly buffer Radii { float radii[]; };
layout(std430, binding = 2) buffer Accum { float accum[]; };
layout(std430, binding = 3) buffer Denom { float denom[]; };
layout(std430, binding = 4) buffer MaxR { float max_radii[]; };
layout(push_constant) uniform Push { uint n; } pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    float r = radii[i];
    if (r > 0.0) {
        float g = length(densify[i]);
        if (!(isnan(g) || isinf(g))) {
            accum[i] += g;
        }
        denom[i] += 1.0;
        max_radii[i] = max(max_radii[i], r);
    }
}
