#version 460
// variant: WRITE
// A view's blend weights, captured once for a set whose geometry and
// opacity no longer train (pipelines/src/raster/kept_weights.rs): the
// forward's walk of each pixel's tile, front to back, span by span, with
// its decisions (the pixel box, the ray-splat hit, alpha >= ALPHA_MIN, the
// stop below T_MIN) and its weight w = alpha T, the same arithmetic as
// raster/forward.comp and raster/forward_sg.comp, so a pixel's colour is
// sum_j w_j c_j + T bg over the splats it blended, in their order.
// One invocation per pixel (tile-major: TILE^2 consecutive invocations are
// one tile), no subgroup operations, no shared memory: it runs once per
// view.
// Default: count each pixel's contributions. WRITE: with each pixel's
// first slot (the counts' prefix sum, from the host) write the Gaussian of
// each contribution and its weight there, and after the last span the
// pixel's final transmittance. The walk's state (T, count, stopped)
// carries over between span passes in `state`.
#include "common.glsl"
#include "raster/common.glsl"

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
// The tile's splats as uniform texel buffers (one gather a read on
// llvmpipe, where a storage-buffer load goes lane by lane).
layout(binding = 2) uniform usamplerBuffer vals_t;
layout(binding = 3) uniform usamplerBuffer gid_t;
layout(binding = 4) uniform samplerBuffer proj_t;
#define PROJ(at) texelFetch(proj_t, int(at)).r
// Per pixel: T, count, stopped (3 planes of width x height words).
layout(std430, binding = 5) buffer State { uint state[]; };
#ifdef WRITE
// [0, npix]: each pixel's first slot; then the Gaussian of each slot.
layout(std430, binding = 6) buffer Pix { uint pix[]; };
// [0, npix): each pixel's final T; then the weight of each slot.
layout(std430, binding = 7) writeonly buffer PixW { float pix_w[]; };
#endif

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    uint per_tile = TILE * TILE;
    uint tile = i / per_tile;
    if (tile >= pc.tiles_x * pc.tiles_y) {
        return;
    }
    uint local = i % per_tile;
    uint tx = tile % pc.tiles_x, ty = tile / pc.tiles_x;
    uvec2 pixel = uvec2(tx * TILE + local % TILE, ty * TILE + local / TILE);
    if (pixel.x >= pc.width || pixel.y >= pc.height) {
        return;
    }
    uint npix = pc.width * pc.height;
    uint px = pixel.y * pc.width + pixel.x;
    vec2 pf = vec2(pixel);
    uvec2 range = ranges[tile];
    uint start = range.x + pc.span_index * pc.span;
    uint end = min(range.y, start + pc.span);
    bool first = pc.span_index == 0u;
    bool last_span = end >= range.y;

    float T = first ? 1.0 : uintBitsToFloat(state[px]);
    uint count = first ? 0u : state[npix + px];
    bool done = first ? false : state[2u * npix + px] != 0u;
#ifdef WRITE
    uint base = pix[px];
#endif
    for (uint q = start; q < end && !done; q++) {
        uint g = texelFetch(gid_t, int(texelFetch(vals_t, int(q)).r)).r;
        uint o = PROJ_STRIDE * g;
        vec4 box = vec4(PROJ(o + 16u), PROJ(o + 17u), PROJ(o + 18u), PROJ(o + 19u));
        if (!in_box(box, pf)) {
            continue;
        }
        vec3 tu = vec3(PROJ(o), PROJ(o + 1u), PROJ(o + 2u));
        vec3 tv = vec3(PROJ(o + 3u), PROJ(o + 4u), PROJ(o + 5u));
        vec3 tw = vec3(PROJ(o + 6u), PROJ(o + 7u), PROJ(o + 8u));
        vec2 mu = vec2(PROJ(o + 9u), PROJ(o + 10u));
        float op = PROJ(o + 14u);
        Hit h;
        bool hit = intersect(tu, tv, tw, mu, pf, h);
        float alpha = hit ? min(ALPHA_MAX, op * h.g) : 0.0;
        if (alpha < ALPHA_MIN) {
            continue;
        }
        float Tn = T * (1.0 - alpha);
        if (Tn < T_MIN) {
            done = true;
            continue;
        }
#ifdef WRITE
        pix[npix + 1u + base + count] = g;
        pix_w[npix + base + count] = alpha * T;
#endif
        count++;
        T = Tn;
    }
    state[px] = floatBitsToUint(T);
    state[npix + px] = count;
    state[2u * npix + px] = done ? 1u : 0u;
#ifdef WRITE
    if (last_span) {
        pix_w[px] = T;
    }
#endif
}
