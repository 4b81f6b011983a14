// Which tiles of a splat's rectangle hold a pixel it can reach, shared by
// the projection (raster/project.comp counts them) and the emission
// (raster/emit.comp writes them). A pixel is blended only where
// min(rho3, rho2) <= k^2 = 2 ln(o / ALPHA_MIN) (raster/project.glsl
// `pixel_bounds_of`): inside the splat-plane ellipse u^2 + v^2 <= k^2 or the
// low-pass disc about mu. A rectangle's corner tiles often meet neither
// (a thin surfel seen along a diagonal: most of them), and every tile a
// splat is binned to lengthens the tile's list, its sort and its per-pixel
// loops. Culling them changes no blend: the tile kernels skip such a splat
// at every pixel of such a tile. The test errs towards keeping a tile: the
// tile's pixel centres are widened by a pixel and k^2 by 0.1%, and a NaN
// or a conic that is not an ellipse along an edge keeps it.
// `precise` keeps the two kernels' arithmetic the same to the bit (no
// contraction into fused multiply-adds in one and not the other).
#ifndef TGS_RASTER_TILE_CULL_GLSL
#define TGS_RASTER_TILE_CULL_GLSL
#include "raster/common.glsl"

// The splat's conic data: p(x) = p0 + (x - mu).x a1 + (x - mu).y a2 is
// hx x hy of `intersect` at pixel x, and u^2 + v^2 <= K iff
// p.x^2 + p.y^2 - K p.z^2 <= 0.
struct TileCull {
    vec3 a1;
    vec3 a2;
    vec3 p0;
    vec2 mu;
    vec2 centre;  // the ellipse's centre on screen
    float K;      // k^2 widened
    float r2;     // the low-pass disc's radius squared
    bool all;     // no ellipse to test against: every tile of the rectangle
};

TileCull tile_cull_of(vec3 tu, vec3 tv, vec3 tw, vec2 mu, float o) {
    TileCull c;
    precise float k2 = 2.0 * log(o / ALPHA_MIN);
    c.K = k2 * 1.001;
    c.r2 = c.K / FILTER_INV_SQUARE;
    c.mu = mu;
    precise vec3 a1 = cross(tv, tw);
    precise vec3 a2 = cross(tw, tu);
    precise vec3 p0 = cross(mu.x * tw - tu, mu.y * tw - tv);
    c.a1 = a1;
    c.a2 = a2;
    c.p0 = p0;
    precise float d = c.K * (tw.x * tw.x + tw.y * tw.y) - tw.z * tw.z;
    precise vec2 centre = vec2(c.K * (tu.x * tw.x + tu.y * tw.y) - tu.z * tw.z, c.K * (tv.x * tw.x + tv.y * tw.y) - tv.z * tw.z) / d;
    c.centre = centre;
    // Near the camera plane the conic is ill-conditioned in f32 (a splat
    // 40 units wide seen nearly edge-on, its bounds 6e6 pixels across,
    // had every tile culled although it reached the image's corner): such
    // splats keep every tile, as tests/src/raster_ref.rs bbox_ill_conditioned
    // judges them, and so do bounds far wider than the grid.
    float scale = c.K * (tw.x * tw.x + tw.y * tw.y) + tw.z * tw.z;
    vec2 grid = vec2(pc.tiles_x, pc.tiles_y) * float(TILE);
    bool wide = any(greaterThan(abs(centre - mu), 16.0 * grid));
    c.all = !(d < -1e-2 * scale) || wide || any(isnan(centre)) || any(isinf(centre)) || !(k2 > 0.0);
    return c;
}

// Whether q = |p.xy|^2 - K p.z^2 along the segment s + t e, t in [0, len]
// (s relative to mu, e a unit axis), can be <= 0.
bool edge_reached(TileCull c, vec2 s, vec2 e, float len) {
    precise vec3 al = c.p0 + s.x * c.a1 + s.y * c.a2;
    precise vec3 be = e.x * c.a1 + e.y * c.a2;
    precise float A = be.x * be.x + be.y * be.y - c.K * be.z * be.z;
    if (!(A > 0.0)) {
        return true;
    }
    precise float B = al.x * be.x + al.y * be.y - c.K * al.z * be.z;
    precise float t = clamp(-B / A, 0.0, len);
    precise vec3 p = al + t * be;
    precise float q = p.x * p.x + p.y * p.y - c.K * p.z * p.z;
    return !(q > 0.0);
}

// Whether tile (tx, ty) holds a pixel centre inside the pixel box `box`
// that the splat can reach.
bool tile_reached(TileCull c, vec4 box, uint tx, uint ty) {
    if (c.all) {
        return true;
    }
    vec2 t0 = vec2(float(tx * TILE), float(ty * TILE));
    vec2 lo = max(t0, box.xy);
    vec2 hi = min(t0 + float(TILE - 1u), box.zw);
    if (any(greaterThan(lo, hi))) {
        return false;  // no pixel of this tile is inside the box
    }
    lo -= 1.0;
    hi += 1.0;
    precise vec2 dd = c.mu - clamp(c.mu, lo, hi);
    if (!(dot(dd, dd) > c.r2)) {
        return true;
    }
    if (all(greaterThanEqual(c.centre, lo)) && all(lessThanEqual(c.centre, hi))) {
        return true;
    }
    vec2 a = lo - c.mu, b = hi - c.mu;
    // The rectangle's middle first: inside the ellipse for most tiles kept.
    precise vec2 m = 0.5 * (a + b);
    precise vec3 pm = c.p0 + m.x * c.a1 + m.y * c.a2;
    if (!(pm.x * pm.x + pm.y * pm.y - c.K * pm.z * pm.z > 0.0)) {
        return true;
    }
    vec2 size = hi - lo;
    return edge_reached(c, a, vec2(1.0, 0.0), size.x) || edge_reached(c, vec2(a.x, b.y), vec2(1.0, 0.0), size.x)
        || edge_reached(c, a, vec2(0.0, 1.0), size.y) || edge_reached(c, vec2(b.x, a.y), vec2(0.0, 1.0), size.y);
}
// The most tiles a rectangle may have for `mask` to list those reached
// (most splats; testing each tile again in the emission cost it as much as
// the rest of its work on lavapipe).
#define MASK_TILES 128u

// Whether the rectangle `rect` (x0, y0, x1, y1) is worth testing: one row
// or one column of tiles is reached whole (the ellipse crosses its
// bounds' every x and y, and the test widens the tiles by a pixel).
bool tiles_to_test(uvec4 rect) {
    return rect.z - rect.x > 1u && rect.w - rect.y > 1u;
}

// The mask of a rectangle of `area` tiles reached whole.
uvec4 mask_all(uint area) {
    uvec4 mask;
    for (uint w = 0u; w < 4u; w++) {
        uint bits = uint(clamp(int(area) - int(32u * w), 0, 32));
        mask[w] = bits == 32u ? 0xFFFFFFFFu : (1u << bits) - 1u;
    }
    return mask;
}

// How many tiles of the rectangle `rect` (x0, y0, x1, y1) the splat
// reaches; where it has at most MASK_TILES, `mask` gets a bit for each
// (tiles in row order), so the emission need not test them again.
uint tiles_reached(vec3 tu, vec3 tv, vec3 tw, vec2 mu, float o, vec4 box, uvec4 rect, out uvec4 mask) {
    uint area = (rect.z - rect.x) * (rect.w - rect.y);
    TileCull c = tile_cull_of(tu, tv, tw, mu, o);
    if (c.all) {
        mask = mask_all(area);
        return area;
    }
    mask = uvec4(0u);
    uint n = 0u, bit = 0u;
    for (uint ty = rect.y; ty < rect.w; ty++) {
        for (uint tx = rect.x; tx < rect.z; tx++) {
            bool hit = tile_reached(c, box, tx, ty);
            n += hit ? 1u : 0u;
            if (hit && bit < MASK_TILES) {
                mask[bit >> 5u] |= 1u << (bit & 31u);
            }
            bit++;
        }
    }
    return n;
}

// Whether bit `bit` of a tile mask is set.
bool mask_bit(uvec4 mask, uint bit) {
    return (mask[bit >> 5u] >> (bit & 31u) & 1u) != 0u;
}
#endif
