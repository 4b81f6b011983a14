#version 460
// variant: RECORDS_BDA
#ifdef RECORDS_BDA
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#endif
// The colour gradient of each Gaussian of a view from its kept blend
// weights (pipelines/src/raster/kept_weights.rs): d c_g = sum w gC[px]
// over the pixels g contributed to, in pixel order (fixed; no atomics).
// One invocation per Gaussian g writes gradient record g (the colour
// entries; the 15 geometric ones zero, as the colour-only tile backward
// leaves them), rank g of the reduce's order (ids[g] = g) and its record
// range [g, g + 1) (offsets), so the per-Gaussian reduce
// (raster/reduce.comp) then applies the SH chain rule and, fused, Adam,
// exactly as after the tile backward. Gaussians past the view have
// no contributions and a zero record. A Gaussian's contributions
// [span_index span, + span) per pass (the loop budget of CPU drivers),
// added to the record the pass before wrote.
#include "common.glsl"
#include "raster/common.glsl"

layout(binding = 0) uniform samplerBuffer gout_t;
layout(binding = 1) uniform usamplerBuffer gau_t;
layout(binding = 2) uniform samplerBuffer gau_w_t;
layout(std430, binding = 3) writeonly buffer Ids { uint ids[]; };
layout(std430, binding = 4) writeonly buffer Offsets { uint offsets[]; };
#define RECORDS_BINDING 5
#define RECORDS_ACCESS
#include "raster/records.glsl"

void main() {
    uint g = wg_linear() * WG + gl_LocalInvocationID.x;
    if (g >= pc.n) {
        return;
    }
    uint npix = pc.width * pc.height;
    uint j0 = texelFetch(gau_t, int(g)).r, j1 = texelFetch(gau_t, int(g + 1u)).r;
    bool first = pc.span_index == 0u;
    uint b = g * KREC;
    float d[CH];
    for (uint c = 0u; c < CH; c++) {
        d[c] = first ? 0.0 : RECORDS[b + 15u + c];
    }
    uint a = min(j1, j0 + pc.span_index * pc.span);
    j1 = min(j1, a + pc.span);
    for (uint j = a; j < j1; j++) {
        uint px = texelFetch(gau_t, int(pc.n + 1u + j)).r;
        float w = texelFetch(gau_w_t, int(j)).r;
        for (uint c = 0u; c < CH; c++) {
            d[c] += w * texelFetch(gout_t, int(c * npix + px)).r;
        }
    }
    for (uint c = 0u; c < CH; c++) {
        RECORDS[b + 15u + c] = d[c];
    }
    if (first) {
        for (uint k = 0u; k < 15u; k++) {
            RECORDS[b + k] = 0.0;
        }
        ids[g] = g;
        offsets[g] = g;
        if (g == 0u) {
            offsets[pc.n] = pc.n;
        }
    }
}
