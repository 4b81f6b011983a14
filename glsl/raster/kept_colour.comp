#version 460
// The colour planes of a view from its kept blend weights
// (raster/capture.comp; pipelines/src/raster/kept_weights.rs), for a set
// whose geometry and opacity are those the weights were captured with:
// out[c][px] = sum_j w_j c_j + T bg_c over the pixel's contributions in
// blending order, with the projection's colours c of this step. The same
// operations in the same order as the tile forward's colour, so the planes
// are the full forward's bit for bit (tests/tests/kept_weights.rs). The
// other planes are not written. One invocation per pixel; a pixel's
// contributions [span_index span, + span) per pass (the loop budget of CPU
// drivers), the sum carried over in the colour planes as the tile forward
// carries it; the last pass (span_index + 1 = spans) adds the background.
#include "common.glsl"
#include "raster/common.glsl"

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
// Read as uniform texel buffers (one gather a read on llvmpipe).
layout(binding = 1) uniform samplerBuffer pfeat_t;
layout(binding = 2) uniform usamplerBuffer pix_t;
layout(binding = 3) uniform samplerBuffer pix_w_t;
layout(std430, binding = 4) buffer Out { float outp[]; };

void main() {
    uint px = wg_linear() * WG + gl_LocalInvocationID.x;
    uint npix = pc.width * pc.height;
    if (px >= npix) {
        return;
    }
    uint j0 = texelFetch(pix_t, int(px)).r, j1 = texelFetch(pix_t, int(px + 1u)).r;
    bool first = pc.span_index == 0u;
    float acc[CH];
    for (uint c = 0u; c < CH; c++) {
        acc[c] = first ? 0.0 : outp[c * npix + px];
    }
    uint a = min(j1, j0 + pc.span_index * pc.span);
    j1 = min(j1, a + pc.span);
    for (uint j = a; j < j1; j++) {
        uint g = texelFetch(pix_t, int(npix + 1u + j)).r;
        float w = texelFetch(pix_w_t, int(npix + j)).r;
        for (uint c = 0u; c < CH; c++) {
            acc[c] += w * texelFetch(pfeat_t, int(g * CH + c)).r;
        }
    }
    bool last = pc.span_index + 1u >= pc.spans;
    float T = texelFetch(pix_w_t, int(px)).r;
    for (uint c = 0u; c < CH; c++) {
        outp[c * npix + px] = acc[c] + (last ? T * cam[20u + c] : 0.0);
    }
}
