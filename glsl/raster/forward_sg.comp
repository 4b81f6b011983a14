#version 460
// variant: COLOUR_ONLY
// Per-pixel 2DGS forward in ONE SUBGROUP per tile (for CPU drivers; see
// raster/backward_sg.comp): invocation l owns the PPT = TILE^2 / WG pixels
// l, l + WG, ... of the tile (8x8 where the frame allows, else 16x16) with
// their blending state in registers and walks the tile's splats front to
// back (each at the pixels of its box only), reading each splat straight
// from the projection buffer (the same address in every invocation): no
// shared-memory staging, no barriers. The math, the outputs and the span
// handling are raster/forward.comp's (method-notes §1.5); the walk stops
// when every pixel of the tile is saturated.
#include "common.glsl"
#include "raster/common.glsl"

layout(constant_id = 6) const uint PPT = 32;  // pixels per invocation; WG * PPT = TILE * TILE

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
// The tile's splats as uniform texel buffers: llvmpipe fetches a texel as
// one gather, where it loads from a storage buffer lane by lane with a
// branch and a spill each (the light field's GEMM, perf/RESULTS.md,
// forty-first entry). Every invocation reads the same splat.
layout(binding = 2) uniform usamplerBuffer vals_t;
layout(binding = 3) uniform usamplerBuffer gid_t;
layout(binding = 4) uniform samplerBuffer proj_t;
layout(binding = 5) uniform samplerBuffer pfeat_t;
#define VALS(at) texelFetch(vals_t, int(at)).r
#define GID(at) texelFetch(gid_t, int(at)).r
#define PROJ(at) texelFetch(proj_t, int(at)).r
#define PFEAT(at) texelFetch(pfeat_t, int(at)).r
layout(std430, binding = 6) buffer Out { float outp[]; };
layout(std430, binding = 7) buffer FState { float fstate[]; };
layout(std430, binding = 8) buffer UState { uint ustate[]; };
layout(std430, binding = 9) buffer Stats { uint stats[]; };
#include "raster/pixel_blend.glsl"

void main() {
    uint tile = wg_linear();
    if (tile >= pc.tiles_x * pc.tiles_y) {
        return;
    }
    uvec2 range = ranges[tile];
    uint start = range.x + pc.span_index * pc.span;
    if (pc.span_index > 0u && start >= range.y) {
        return;
    }
    uint end = min(range.y, start + pc.span);
    bool last_span = end >= range.y;
    uint lid = gl_LocalInvocationID.x;
    if (!last_span && pc.span_index + 1u == pc.spans && lid == 0u) {
        stats[1] = 1u;  // this tile needs more span passes than were recorded
    }
    uint tx = tile % pc.tiles_x, ty = tile / pc.tiles_x;
    uint plane = pc.width * pc.height;

    vec2 pfs[PPT];
    uint pxs[PPT];
    bool ins[PPT];
    PixelState ps[PPT];
    float accs[PPT * CH];
    uint n_done = 0u;
    bool resume = pc.span_index > 0u;
    for (uint k = 0u; k < PPT; k++) {
        uint i = lid + k * WG;
        uvec2 pix = uvec2(tx * TILE + (i % TILE), ty * TILE + (i / TILE));
        bool inside = pix.x < pc.width && pix.y < pc.height;
        uint px = pix.y * pc.width + pix.x;
        pfs[k] = vec2(pix);
        pxs[k] = px;
        ins[k] = inside;
        ps[k] = load_pixel(px, inside, resume);
        for (uint c = 0u; c < CH; c++) {
            accs[k * CH + c] = inside && resume ? outp[c * plane + px] : 0.0;
        }
        n_done += ps[k].done ? 1u : 0u;
    }

    float feat[CH];
    for (uint q = start; q < end && !subgroupAll(n_done == PPT); q++) {
        uint g = GID(VALS(q));
        uint o = PROJ_STRIDE * g;
        vec3 tu = vec3(PROJ(o), PROJ(o + 1u), PROJ(o + 2u));
        vec3 tv = vec3(PROJ(o + 3u), PROJ(o + 4u), PROJ(o + 5u));
        vec3 tw = vec3(PROJ(o + 6u), PROJ(o + 7u), PROJ(o + 8u));
        vec2 mu = vec2(PROJ(o + 9u), PROJ(o + 10u));
        vec3 nrm = vec3(PROJ(o + 11u), PROJ(o + 12u), PROJ(o + 13u));
        float op = PROJ(o + 14u);
        vec4 box = vec4(PROJ(o + 16u), PROJ(o + 17u), PROJ(o + 18u), PROJ(o + 19u));
        for (uint c = 0u; c < CH; c++) {
            feat[c] = PFEAT(g * CH + c);
        }
        // Only the pixels of the splat's box. (Every slot is visited: a
        // loop of constant length keeps the pixel state in registers, which
        // on llvmpipe is worth more than skipping the rows the box misses.)
        for (uint k = 0u; k < PPT; k++) {
            if (ps[k].done || !in_box(box, pfs[k])) {
                continue;
            }
            Hit h;
            bool hit = intersect(tu, tv, tw, mu, pfs[k], h);
            float alpha = hit ? min(ALPHA_MAX, op * h.g) : 0.0;
            if (alpha < ALPHA_MIN) {
                continue;
            }
            float Tn = ps[k].T * (1.0 - alpha);
            if (Tn < T_MIN) {
                ps[k].done = true;
                n_done++;
                continue;
            }
            float w = blend(ps[k], h, alpha, Tn, nrm, q);
            for (uint c = 0u; c < CH; c++) {
                accs[k * CH + c] += w * feat[c];
            }
        }
    }

    for (uint k = 0u; k < PPT; k++) {
        if (!ins[k]) {
            continue;
        }
        for (uint c = 0u; c < CH; c++) {
            outp[c * plane + pxs[k]] = accs[k * CH + c] + (last_span ? ps[k].T * cam[20u + c] : 0.0);
        }
        store_pixel(pxs[k], ps[k]);
    }
}
