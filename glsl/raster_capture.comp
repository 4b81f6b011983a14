#version 460
// variant: WRITE
// A view's blend weights, captured once for a set whose geometry and
// opacity no longer train (pipelines/src/raster/kept_weights.rs): the
// forward's walk of each pixel's tile, front to back, span by span, with
// its decisions (the pixel box, the ray-splat hit, alpha >= ALPHA_MIN, the
// stop below T_MIN) and its weight w = alpha T, the same arithmetic as
// raster_forward.comp and raster_forward_sg.comp, so a pixel's colour is
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
#include "raster_common.glsl"

layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
layout(std430, binding = 1) readonly buffer Ranges { uvec2 ranges[]; };
layout(std430, binding = 2) readonly buffer Vals { uint vals[]; };
layout(std430, binding = 3) readonly buffer Gid { uint gid[]; };
layout(std430, binding = 4) readonly buffer Proj { float proj[]; };
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
        uint g = gid[vals[q]];
        uint o = PROJ_STRIDE * g;
        vec4 box = vec4(proj[o + 16u], proj[o + 17u], proj[o + 18u], proj[o + 19u]);
        if (!in_box(box, pf)) {
            continue;
        }
        vec3 tu = vec3(proj[o], proj[o + 1u], proj[o + 2u]);
        vec3 tv = vec3(proj[o + 3u], proj[o + 4u], proj[o + 5u]);
        vec3 tw = vec3(proj[o + 6u], proj[o + 7u], proj[o + 8u]);
        vec2 mu = vec2(proj[o + 9u], proj[o + 10u]);
        float op = proj[o + 14u];
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
