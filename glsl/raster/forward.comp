#version 460
// variant: COLOUR_ONLY
// Per-pixel 2DGS forward (method-notes §1.5): one 16x16 workgroup per tile
// (TILE is 16 for these kernels), splats staged in shared memory in batches
// of 256, front to back, each evaluated at the pixels of its box only.
//
// Long tile lists are cut into spans of `pc.span` splats; pass k handles span
// k of every tile, carrying per-pixel state in the output/state planes, so no
// invocation runs more than about `span` loop iterations (lavapipe stops
// loops after 65,535). The pass of a tile's last span adds the background.
//
// Planes (W*H floats each): out = CH features, alpha, depth numerator,
// normal (3), median depth, distortion; fstate = T, M1, M2;
// ustate = last contributor + 1, median contributor, done flag.
#include "common.glsl"
#include "raster/common.glsl"

layout(local_size_x_id = 0) in;  // must be 256 (TILE * TILE)

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, binding = 2) readonly buffer Vals { uint vals[]; };
layout(std430, binding = 3) readonly buffer Gid { uint gid[]; };
layout(std430, binding = 4) readonly buffer ProjIn { float proj[]; };
layout(std430, binding = 5) readonly buffer FeatIn { float pfeat[]; };
layout(std430, binding = 6) buffer Out { float outp[]; };
layout(std430, binding = 7) buffer FState { float fstate[]; };
layout(std430, binding = 8) buffer UState { uint ustate[]; };
layout(std430, binding = 9) buffer Stats { uint stats[]; };
#include "raster/pixel_blend.glsl"

shared vec3 s_tu[256];
shared vec3 s_tv[256];
shared vec3 s_tw[256];
shared vec3 s_muo[256];
shared uint s_g[256];
shared vec4 s_box[256];

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
    if (!last_span && pc.span_index + 1u == pc.spans && gl_LocalInvocationID.x == 0u) {
        stats[1] = 1u;  // this tile needs more span passes than were recorded
    }

    uint lid = gl_LocalInvocationID.x;
    uint tx = tile % pc.tiles_x, ty = tile / pc.tiles_x;
    uvec2 pix = uvec2(tx * TILE + (lid % TILE), ty * TILE + (lid / TILE));
    bool inside = pix.x < pc.width && pix.y < pc.height;
    uint plane = pc.width * pc.height;
    uint px = pix.y * pc.width + pix.x;
    vec2 pf = vec2(pix);

    bool resume = pc.span_index > 0u;
    PixelState p = load_pixel(px, inside, resume);
    float acc[CH];
    for (uint c = 0u; c < CH; c++) {
        acc[c] = inside && resume ? outp[c * plane + px] : 0.0;
    }

    for (uint b = start; b < end; b += 256u) {
        barrier();
        uint q = b + lid;
        if (q < end) {
            uint g = gid[vals[q]];
            uint o = PROJ_STRIDE * g;
            s_box[lid] = vec4(proj[o + 16u], proj[o + 17u], proj[o + 18u], proj[o + 19u]);
            s_tu[lid] = vec3(proj[o], proj[o + 1u], proj[o + 2u]);
            s_tv[lid] = vec3(proj[o + 3u], proj[o + 4u], proj[o + 5u]);
            s_tw[lid] = vec3(proj[o + 6u], proj[o + 7u], proj[o + 8u]);
            s_muo[lid] = vec3(proj[o + 9u], proj[o + 10u], proj[o + 14u]);
            s_g[lid] = g;
        }
        barrier();
        uint cnt = min(256u, end - b);
        for (uint j = 0u; j < cnt && !p.done; j++) {
            Hit h;
            vec3 muo = s_muo[j];
            if (!in_box(s_box[j], pf) || !intersect(s_tu[j], s_tv[j], s_tw[j], muo.xy, pf, h)) {
                continue;
            }
            float alpha = min(ALPHA_MAX, muo.z * h.g);
            if (alpha < ALPHA_MIN) {
                continue;
            }
            float Tn = p.T * (1.0 - alpha);
            if (Tn < T_MIN) {
                p.done = true;
                break;
            }
            uint g = s_g[j];
            vec3 nrm = vec3(proj[PROJ_STRIDE * g + 11u], proj[PROJ_STRIDE * g + 12u], proj[PROJ_STRIDE * g + 13u]);
            float w = blend(p, h, alpha, Tn, nrm, b + j);
            for (uint c = 0u; c < CH; c++) {
                acc[c] += w * pfeat[g * CH + c];
            }
        }
    }

    if (!inside) {
        return;
    }
    for (uint c = 0u; c < CH; c++) {
        outp[c * plane + px] = acc[c] + (last_span ? p.T * cam[20u + c] : 0.0);
    }
    store_pixel(px, p);
}
