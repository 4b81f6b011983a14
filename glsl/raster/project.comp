#version 460
// One invocation per Gaussian: the 2DGS splat-to-pixel transform, bounding
// box and tile rectangle, view-dependent features, and the depth sort key.
// Culled Gaussians get zero tiles and the largest key.
// Variant TEXEL (CPU devices): the camera and the Gaussians are read as
// uniform texel buffers, which llvmpipe fetches as one gather where it
// loads a storage buffer lane by lane (perf/RESULTS.md, forty-first entry).
// Variant COLOUR (a view rendered from kept blend weights,
// pipelines/src/raster/kept_weights.rs: the geometry is frozen and the
// view's splats were captured with its weights): the features alone, for
// every Gaussian, as the full kernel computes them; nothing else is
// written (a store is a loop over the lanes on CPU drivers, and the splat,
// rectangle, key and radius stores were most of this kernel there).
// variant: TEXEL
// variant: COLOUR
// variant: TEXEL COLOUR
#include "common.glsl"

#ifdef TEXEL
layout(binding = 0) uniform samplerBuffer cam_t;
layout(binding = 1) uniform samplerBuffer means_t;
layout(binding = 2) uniform samplerBuffer scales_t;
layout(binding = 3) uniform samplerBuffer quats_t;
layout(binding = 4) uniform samplerBuffer opacity_t;
layout(binding = 5) uniform samplerBuffer feats_t;
#define CAM(at) texelFetch(cam_t, int(at)).r
#define MEANS(at) texelFetch(means_t, int(at)).r
#define LOG_SCALES(at) texelFetch(scales_t, int(at)).r
#define QUAT(at) vec4(texelFetch(quats_t, int(4u * (at))).r, texelFetch(quats_t, int(4u * (at) + 1u)).r, texelFetch(quats_t, int(4u * (at) + 2u)).r, texelFetch(quats_t, int(4u * (at) + 3u)).r)
#define OPACITY(at) texelFetch(opacity_t, int(at)).r
#define FEATS(at) texelFetch(feats_t, int(at)).r
#else
layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Means { float means[]; };
layout(std430, binding = 2) readonly buffer Scales { float log_scales[]; };
layout(std430, binding = 3) readonly buffer Quats { vec4 quats[]; };
layout(std430, binding = 4) readonly buffer Opac { float opacity[]; };
layout(std430, binding = 5) readonly buffer Feats { float feats[]; };
#define MEANS(at) means[at]
#define LOG_SCALES(at) log_scales[at]
#define QUAT(at) quats[at]
#define OPACITY(at) opacity[at]
#define FEATS(at) feats[at]
#endif
layout(std430, binding = 6) writeonly buffer ProjOut { float proj[]; };
layout(std430, binding = 7) writeonly buffer FeatOut { float pfeat[]; };
layout(std430, binding = 8) writeonly buffer Rects { uvec4 rects[]; };
layout(std430, binding = 9) writeonly buffer Tiles { uint tiles[]; };
layout(std430, binding = 10) writeonly buffer Keys { uint depth_keys[]; };
layout(std430, binding = 11) writeonly buffer Ids { uint depth_ids[]; };
// Screen radius in pixels (0 when culled): densification statistics.
layout(std430, binding = 12) writeonly buffer Radii { float radii[]; };
// The tiles of its rectangle it reaches (emit.comp reads them where it
// has two rows and two columns or more, at most MASK_TILES tiles).
layout(std430, binding = 13) writeonly buffer TileMasks { uvec4 tile_masks[]; };

#include "raster/project.glsl"
#include "raster/tile_cull.glsl"

void main() {
    // The Gaussians of this slice (pc.feat_base on; all of them unsliced).
    uint g = pc.feat_base + wg_linear() * WG + gl_LocalInvocationID.x;
    if (g >= min(pc.n, pc.feat_end)) {
        return;
    }
    vec3 p = vec3(MEANS(3u * g), MEANS(3u * g + 1u), MEANS(3u * g + 2u));
#ifndef COLOUR
    depth_ids[g] = g;
    vec2 ls = vec2(LOG_SCALES(2u * g), LOG_SCALES(2u * g + 1u));
    Proj pr;
    bool ok = project(p, ls, QUAT(g), OPACITY(g), pr);
    uvec4 rect = uvec4(0u);
    vec4 box = vec4(0.0);
    if (ok) {
        bool bounded;
        vec4 b = pixel_bounds_of(pr, bounded);
        rect = tile_rect(b);
        box = pixel_box(b, bounded);
    }
    uint count = (rect.z - rect.x) * (rect.w - rect.y);
    rects[g] = rect;
    if (tiles_to_test(rect)) {
        uvec4 mask;
        tiles[g] = tiles_reached(pr.s.tu, pr.s.tv, pr.s.tw, pr.s.mu, pr.s.o, box, rect, mask);
        tile_masks[g] = mask;
    } else {
        tiles[g] = count;
    }
    radii[g] = count > 0u ? pr.radius : 0.0;
    depth_keys[g] = count > 0u ? floatBitsToUint(pr.pv.z) : 0xFFFFFFFFu;
    if (count == 0u) {
        return;
    }
    uint b = PROJ_STRIDE * g;
    proj[b + 0u] = pr.s.tu.x; proj[b + 1u] = pr.s.tu.y; proj[b + 2u] = pr.s.tu.z;
    proj[b + 3u] = pr.s.tv.x; proj[b + 4u] = pr.s.tv.y; proj[b + 5u] = pr.s.tv.z;
    proj[b + 6u] = pr.s.tw.x; proj[b + 7u] = pr.s.tw.y; proj[b + 8u] = pr.s.tw.z;
    proj[b + 9u] = pr.s.mu.x; proj[b + 10u] = pr.s.mu.y;
    proj[b + 11u] = pr.s.n.x; proj[b + 12u] = pr.s.n.y; proj[b + 13u] = pr.s.n.z;
    proj[b + 14u] = pr.s.o; proj[b + 15u] = pr.pv.z;
    proj[b + 16u] = box.x; proj[b + 17u] = box.y; proj[b + 18u] = box.z; proj[b + 19u] = box.w;
#endif

    // Features: SH evaluated for the view direction (+0.5, clamped at 0), or plain.
    uint fb = (g - pc.feat_base) * pc.coeffs * CH;
    if (pc.mode == 1u) {
        for (uint c = 0u; c < CH; c++) {
            pfeat[g * CH + c] = FEATS(fb + c);
        }
        return;
    }
    float Y[16];
    vec3 dir = p - cam_centre();
    float len = length(dir);
    sh_basis(len > 0.0 ? dir / len : vec3(0.0, 0.0, 1.0), Y);
    uint nk = active_coeffs();
    for (uint c = 0u; c < CH; c++) {
        float v = 0.5;
        for (uint k = 0u; k < nk; k++) {
            v += Y[k] * FEATS(fb + k * CH + c);
        }
        pfeat[g * CH + c] = max(v, 0.0);
    }
}
