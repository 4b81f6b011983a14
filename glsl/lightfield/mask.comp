#version 460
// flags[pix] = 1 where the light field is evaluated (R > threshold), else 0.
#include "lightfield/common.glsl"

layout(std430, binding = 1) writeonly buffer Flags { uint flags[]; };

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    if (pix < npix()) {
        flags[pix] = evaluated(pix) ? 1u : 0u;
    }
}
