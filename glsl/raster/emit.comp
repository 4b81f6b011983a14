#version 460
// One invocation per depth-ranked Gaussian r: emits its intersections at
// [offsets[r], offsets[r + 1]) (so a Gaussian's intersections are contiguous
// and in depth order overall): tile key, emission index, Gaussian id; the
// tiles of its rectangle it can reach (raster/tile_cull.glsl, as
// project.comp counted them: from its mask where the rectangle has at most
// MASK_TILES, tested again where it has more), or the whole rectangle when
// that is one row or one column of tiles. Should the count and the tiles
// ever disagree, the slots left are filled with the rectangle's other tiles
// (where the tile kernels skip the splat), never left unwritten.
// Intersections past the capacity are dropped (the plan records the total).
// The three cases are three loops under real branches: one loop choosing
// its test per tile had llvmpipe evaluate the conic test for every lane
// (the emission about 11 ms a frame against 7.6; sixty-ninth journal).
#include "common.glsl"
#include "raster/common.glsl"
#include "raster/tile_cull.glsl"

layout(std430, binding = 0) readonly buffer Ids { uint ids[]; };
layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) readonly buffer Rects { uvec4 rects[]; };
layout(std430, binding = 3) writeonly buffer Keys { uint keys[]; };
layout(std430, binding = 4) writeonly buffer Vals { uint vals[]; };
layout(std430, binding = 5) writeonly buffer Gid { uint gid[]; };
layout(std430, binding = 6) readonly buffer ProjIn { float proj[]; };
layout(std430, binding = 7) readonly buffer TileMasks { uvec4 tile_masks[]; };

void emit(uint p, uint key, uint g) {
    keys[p] = key;
    vals[p] = p;
    gid[p] = g;
}

void main() {
    uint r = wg_linear() * WG + gl_LocalInvocationID.x;
    if (r >= pc.n) {
        return;
    }
    uint g = ids[r];
    uint p = offsets[r];
    uint end = min(offsets[r + 1u], pc.capacity);
    if (p >= end) {
        return;
    }
    uvec4 rc = rects[g];
    if (!tiles_to_test(rc)) {
        // One row or one column: every tile.
        for (uint ty = rc.y; ty < rc.w && p < end; ty++) {
            for (uint tx = rc.x; tx < rc.z && p < end; tx++) {
                emit(p, ty * pc.tiles_x + tx, g);
                p++;
            }
        }
        return;
    }
    uint area = (rc.z - rc.x) * (rc.w - rc.y);
    if (area > MASK_TILES) {
        uint o = PROJ_STRIDE * g;
        vec4 box = vec4(proj[o + 16u], proj[o + 17u], proj[o + 18u], proj[o + 19u]);
        TileCull c = tile_cull_of(vec3(proj[o], proj[o + 1u], proj[o + 2u]), vec3(proj[o + 3u], proj[o + 4u], proj[o + 5u]),
                                  vec3(proj[o + 6u], proj[o + 7u], proj[o + 8u]), vec2(proj[o + 9u], proj[o + 10u]), proj[o + 14u]);
        // pass 0: the tiles reached; pass 1 (only on a disagreement): the others.
        for (uint pass = 0u; pass < 2u && p < end; pass++) {
            for (uint ty = rc.y; ty < rc.w && p < end; ty++) {
                for (uint tx = rc.x; tx < rc.z && p < end; tx++) {
                    if (tile_reached(c, box, tx, ty) == (pass == 0u)) {
                        emit(p, ty * pc.tiles_x + tx, g);
                        p++;
                    }
                }
            }
        }
        return;
    }
    uvec4 mask = tile_masks[g];
    for (uint pass = 0u; pass < 2u && p < end; pass++) {
        uint bit = 0u;
        for (uint ty = rc.y; ty < rc.w && p < end; ty++) {
            for (uint tx = rc.x; tx < rc.z && p < end; tx++) {
                if (mask_bit(mask, bit) == (pass == 0u)) {
                    emit(p, ty * pc.tiles_x + tx, g);
                    p++;
                }
                bit++;
            }
        }
    }
}
