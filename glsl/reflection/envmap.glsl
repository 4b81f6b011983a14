// The learnable environment cube map E (method-notes §2.6, §3.4): six faces
// of res x res texels in the order +X, -X, +Y, -Y, +Z, -Z, three raw
// (pre-sigmoid) channels per texel, texel t = (face * res + row) * res + col
// at floats [3t, 3t + 3). E(d) = sigmoid(bilinear(raw)) per channel.
//
// Face coordinates (x, y) in [-1, 1] with x along columns and y along rows
// (row 0 at y = -1); a texel centre (col, row) sits at
// x = 2 (col + 0.5) / res - 1. A tap that falls off its face (across a seam
// or a corner) takes the nearest texel of the face its extrapolated
// direction lands on, so the lookup is continuous across seams (a tap off
// a corner takes the face's own corner texel).
//
// Expects `float env[]` (raw texels) declared before inclusion.
#ifndef TGS_ENVMAP_GLSL
#define TGS_ENVMAP_GLSL

// Direction of the face point (x, y) (the table of method-notes §2.6).
vec3 face_dir(uint face, vec2 xy) {
    float x = xy.x, y = xy.y;
    switch (face) {
        case 0u: return vec3(1.0, -y, -x);
        case 1u: return vec3(-1.0, -y, x);
        case 2u: return vec3(x, 1.0, y);
        case 3u: return vec3(x, -1.0, -y);
        case 4u: return vec3(x, -y, 1.0);
        default: return vec3(-x, -y, -1.0);
    }
}

// Face, face coordinates and their Jacobian d(x, y)/d(d) (rows) of a
// direction, by the major-axis rule (ties go to x, then y). The zero
// direction maps to the centre of +Z with a zero Jacobian.
uint cube_coords(vec3 d, out vec2 xy, out vec3 jx, out vec3 jy) {
    vec3 a = abs(d);
    uint axis = (a.x >= a.y && a.x >= a.z) ? 0u : (a.y >= a.z ? 1u : 2u);
    float ma = a[axis];
    xy = vec2(0.0);
    jx = vec3(0.0);
    jy = vec3(0.0);
    if (!(ma > 0.0) || isinf(ma)) {
        return 4u;
    }
    bool neg = d[axis] < 0.0;
    uint face = 2u * axis + (neg ? 1u : 0u);
    // x = nx . d / ma, y = ny . d / ma with constant numerator vectors.
    vec3 nx, ny;
    switch (face) {
        case 0u: nx = vec3(0, 0, -1); ny = vec3(0, -1, 0); break;
        case 1u: nx = vec3(0, 0, 1); ny = vec3(0, -1, 0); break;
        case 2u: nx = vec3(1, 0, 0); ny = vec3(0, 0, 1); break;
        case 3u: nx = vec3(1, 0, 0); ny = vec3(0, 0, -1); break;
        case 4u: nx = vec3(1, 0, 0); ny = vec3(0, -1, 0); break;
        default: nx = vec3(-1, 0, 0); ny = vec3(0, -1, 0); break;
    }
    float inv = 1.0 / ma;
    xy = vec2(dot(nx, d), dot(ny, d)) * inv;
    vec3 dma = vec3(0.0);
    dma[axis] = neg ? -1.0 : 1.0;
    jx = (nx - xy.x * dma) * inv;
    jy = (ny - xy.y * dma) * inv;
    return face;
}

// Texel index of tap (col, row) of `face`, which may lie one texel off the
// face: then the nearest texel of the face its direction lands on.
uint env_tap(uint face, int col, int row, uint res) {
    int r = int(res);
    bool col_in = col >= 0 && col < r, row_in = row >= 0 && row < r;
    if (col_in == row_in) {
        // On the face, or off a corner, where three faces meet and no
        // neighbour is nearest: the face's own corner texel.
        uvec2 c = uvec2(clamp(ivec2(col, row), ivec2(0), ivec2(r - 1)));
        return (face * res + c.y) * res + c.x;
    }
    vec2 xy = (vec2(col, row) + 0.5) * (2.0 / float(res)) - 1.0;
    vec3 jx, jy;
    vec2 xy2;
    uint f2 = cube_coords(face_dir(face, xy), xy2, jx, jy);
    ivec2 cr = clamp(ivec2(floor((xy2 + 1.0) * (0.5 * float(res)))), ivec2(0), ivec2(r - 1));
    return (f2 * res + uint(cr.y)) * res + uint(cr.x);
}

// Bilinear footprint of a direction: four texels, their weights, and the
// weights' derivatives with respect to the direction (dw[k] = d w_k / d d).
struct EnvTaps {
    uint idx[4];
    float w[4];
    vec3 dw[4];
};

EnvTaps env_taps(vec3 d, uint res) {
    vec2 xy;
    vec3 jx, jy;
    uint face = cube_coords(d, xy, jx, jy);
    float h = 0.5 * float(res);
    vec2 uv = (xy + 1.0) * h - 0.5;
    vec2 f0 = floor(uv);
    vec2 fr = uv - f0;
    ivec2 i0 = ivec2(f0);
    // d uv / d d = h * J.
    vec3 du = h * jx, dv = h * jy;
    EnvTaps t;
    t.idx[0] = env_tap(face, i0.x, i0.y, res);
    t.idx[1] = env_tap(face, i0.x + 1, i0.y, res);
    t.idx[2] = env_tap(face, i0.x, i0.y + 1, res);
    t.idx[3] = env_tap(face, i0.x + 1, i0.y + 1, res);
    t.w[0] = (1.0 - fr.x) * (1.0 - fr.y);
    t.w[1] = fr.x * (1.0 - fr.y);
    t.w[2] = (1.0 - fr.x) * fr.y;
    t.w[3] = fr.x * fr.y;
    t.dw[0] = -(1.0 - fr.y) * du - (1.0 - fr.x) * dv;
    t.dw[1] = (1.0 - fr.y) * du - fr.x * dv;
    t.dw[2] = -fr.y * du + (1.0 - fr.x) * dv;
    t.dw[3] = fr.y * du + fr.x * dv;
    return t;
}

vec3 env_texel(uint t) {
    return vec3(env[3u * t], env[3u * t + 1u], env[3u * t + 2u]);
}

// Pre-sigmoid bilinear value of the taps.
vec3 env_raw(EnvTaps t) {
    vec3 u = vec3(0.0);
    for (uint k = 0u; k < 4u; k++) {
        u += t.w[k] * env_texel(t.idx[k]);
    }
    return u;
}

vec3 sigmoid3(vec3 u) {
    return 1.0 / (1.0 + exp(-u));
}

#endif
