// Shared definitions of the 2DGS rasterizer (method-notes §1.3–1.7).
//
// Specialization constants (besides common.glsl's 0..2):
//   4: CH     feature channels per Gaussian (colour = 3; any 1..32)
//   5: BATCH  splats per shared-memory reduction round in the backward
//   7: TILE   tile side in pixels (below)
//
// Camera buffer (floats): [0..12) world->view rows (R | t), row-major;
// [12..16) fx fy cx cy (pixel centres at integer coordinates);
// [16..19) camera centre in world space; [20..20+CH) background.
#ifndef TGS_RASTER_COMMON_GLSL
#define TGS_RASTER_COMMON_GLSL
#include "common.glsl"

layout(constant_id = 4) const uint CH = 3;
layout(constant_id = 5) const uint BATCH = 8;

// Tile side in pixels (spec constant 7: 16, or 8 for the one-subgroup
// kernels where the frame allows; pipelines/src/raster/tiles.rs).
layout(constant_id = 7) const uint TILE = 16;
#define NEAR 0.2
#define FAR 100.0
#define FILTER_INV_SQUARE 2.0
#define FILTER_SIZE 0.707106
#define CUTOFF 3.0
#define ALPHA_MAX 0.99
#define ALPHA_MIN (1.0 / 255.0)
#define T_MIN 0.0001
// Per-intersection gradient record: dTu 3, dTv 3, dTw 3, dmu 2, dopacity 1,
// dnormal 3, then CH feature gradients.
#define KREC (15u + CH)
// Output planes: CH features, alpha, depth numerator, normal (3), median
// depth, distortion.
#define P_ALPHA (CH)
#define P_DEPTH (CH + 1u)
#define P_NORMAL (CH + 2u)
#define P_MEDIAN (CH + 5u)
#define P_DIST (CH + 6u)

layout(push_constant) uniform Push {
    uint n;          // Gaussians
    uint width;
    uint height;
    uint tiles_x;
    uint tiles_y;
    uint coeffs;     // feature coefficients per channel: (degree_max + 1)^2, or 1
    uint degree;     // active SH degree
    uint mode;       // 0: SH colour (+0.5, clamped >= 0); 1: plain features
    uint capacity;   // intersection capacity
    uint span;       // splats per span (tiles longer than this take several passes)
    uint span_index; // which span this pass handles
    uint spans;      // span passes recorded
    // The Gaussians [feat_base, feat_end) whose features (and, in the
    // reduce, their moments or gradients) the feature bindings hold, from
    // feature feat_base coeffs CH on: a set whose features exceed one
    // storage binding is projected and reduced in slices
    // (pipelines/src/raster feature_slices); 0 and ~0 otherwise.
    uint feat_base;
    uint feat_end;
#ifdef ADAM
    // The reduce with the Adam step fused (raster/reduce.comp, variant ADAM):
    // rates of means, log-scales, rotations, opacity, features (the first
    // `feat_split` of each Gaussian's features; the rest use lr_rest), the
    // number of each Gaussian's features stepped, and Adam's constants
    // (bc1 = 1 - beta1^t, bc2 = 1 - beta2^t).
    float lr_means, lr_scales, lr_quats, lr_opacity, lr_feats, lr_rest;
    uint feat_split;
    uint feat_active;
    float beta1, beta2, eps, bc1, bc2;
#endif
} pc;

// Floats per projected splat in the projection buffer: the Splat below
// (tu, tv, tw, mu, n, o: 0..15), the view depth (15), and the pixel box
// (16..20: lo.x, lo.y, hi.x, hi.y) outside which the splat's alpha stays
// below ALPHA_MIN (raster/project.glsl `pixel_box`).
#define PROJ_STRIDE 20u

// Projected splat: what the rasterizer needs.
struct Splat {
    vec3 tu, tv, tw;  // rows of the splat-to-pixel homography T
    vec2 mu;          // centre of the 3-sigma bounding box (pixels)
    vec3 n;           // view-space normal facing the camera
    float o;          // activated opacity
};

// Rotation from a normalized quaternion (r, x, y, z); columns t_u, t_v, t_w.
mat3 quat_to_rot(vec4 q) {
    float r = q.x, x = q.y, y = q.z, z = q.w;
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + r * z), 2.0 * (x * z - r * y),
        2.0 * (x * y - r * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + r * x),
        2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y));
}

float ndc_depth(float z) {
    return FAR / (FAR - NEAR) * (1.0 - NEAR / z);
}

// Real spherical harmonics up to degree 3 (the 3DGS convention) and their
// gradients with respect to the (unit) direction.
const float SH_C0 = 0.28209479177387814;
const float SH_C1 = 0.4886025119029199;
const float SH_C2[5] = float[5](1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396);
const float SH_C3[7] = float[7](-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154, -0.4570457994644658, 1.445305721320277, -0.5900435899266435);

void sh_basis(vec3 d, out float Y[16]) {
    float x = d.x, y = d.y, z = d.z;
    float xx = x * x, yy = y * y, zz = z * z;
    Y[0] = SH_C0;
    Y[1] = -SH_C1 * y; Y[2] = SH_C1 * z; Y[3] = -SH_C1 * x;
    Y[4] = SH_C2[0] * x * y; Y[5] = SH_C2[1] * y * z; Y[6] = SH_C2[2] * (2.0 * zz - xx - yy);
    Y[7] = SH_C2[3] * x * z; Y[8] = SH_C2[4] * (xx - yy);
    Y[9] = SH_C3[0] * y * (3.0 * xx - yy); Y[10] = SH_C3[1] * x * y * z;
    Y[11] = SH_C3[2] * y * (4.0 * zz - xx - yy); Y[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    Y[13] = SH_C3[4] * x * (4.0 * zz - xx - yy); Y[14] = SH_C3[5] * z * (xx - yy);
    Y[15] = SH_C3[6] * x * (xx - 3.0 * yy);
}

void sh_basis_grad(vec3 d, out vec3 dY[16]) {
    float x = d.x, y = d.y, z = d.z;
    float xx = x * x, yy = y * y, zz = z * z;
    dY[0] = vec3(0.0);
    dY[1] = vec3(0.0, -SH_C1, 0.0); dY[2] = vec3(0.0, 0.0, SH_C1); dY[3] = vec3(-SH_C1, 0.0, 0.0);
    dY[4] = SH_C2[0] * vec3(y, x, 0.0); dY[5] = SH_C2[1] * vec3(0.0, z, y);
    dY[6] = SH_C2[2] * vec3(-2.0 * x, -2.0 * y, 4.0 * z); dY[7] = SH_C2[3] * vec3(z, 0.0, x);
    dY[8] = SH_C2[4] * vec3(2.0 * x, -2.0 * y, 0.0);
    dY[9] = SH_C3[0] * vec3(6.0 * x * y, 3.0 * xx - 3.0 * yy, 0.0);
    dY[10] = SH_C3[1] * vec3(y * z, x * z, x * y);
    dY[11] = SH_C3[2] * vec3(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z);
    dY[12] = SH_C3[3] * vec3(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy);
    dY[13] = SH_C3[4] * vec3(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z);
    dY[14] = SH_C3[5] * vec3(2.0 * x * z, -2.0 * y * z, xx - yy);
    dY[15] = SH_C3[6] * vec3(3.0 * xx - 3.0 * yy, -6.0 * x * y, 0.0);
}

// Number of SH coefficients evaluated at the active degree.
uint active_coeffs() {
    uint d = min(pc.degree, 3u);
    return min((d + 1u) * (d + 1u), pc.coeffs);
}

// Ray-splat intersection of pixel `pix` with a splat (2DGS Eq. 8-10) and the
// object-space low-pass filter. Returns false when the ray is parallel to the
// splat or the hit is in front of the near plane.
struct Hit {
    vec3 hx, hy, p;
    vec2 uv;
    float rho3, rho2, g, z;
};

// Whether pixel `pix` lies in a splat's pixel box (PROJ_STRIDE): the tile
// kernels evaluate a splat only there, skipping the ray-splat intersection
// of pixels it cannot reach.
bool in_box(vec4 box, vec2 pix) {
    return all(greaterThanEqual(pix, box.xy)) && all(lessThanEqual(pix, box.zw));
}

// The one-subgroup tile kernels (WG invocations, PPT pixels each: slot k of
// invocation l is pixel l + k WG of the tile, row (l + k WG) / TILE): the
// slots [x, y) whose rows can meet `box` in tile row `ty`. The same range
// for every invocation, so a CPU driver runs only those iterations.
uvec2 box_slots(vec4 box, uint ty, uint ppt) {
    float top = float(ty * TILE);
    float r0 = clamp(ceil(box.y) - top, 0.0, float(TILE));
    float r1 = clamp(floor(box.w) - top, -1.0, float(TILE - 1u));
    if (!(r1 >= r0)) {
        return uvec2(0u);
    }
    uint y0 = uint(r0), y1 = uint(r1);
    return uvec2(min(TILE * y0 / WG, ppt), min((TILE * y1 + TILE - 1u) / WG + 1u, ppt));
}

bool intersect(vec3 tu, vec3 tv, vec3 tw, vec2 mu, vec2 pix, out Hit h) {
    h.hx = pix.x * tw - tu;
    h.hy = pix.y * tw - tv;
    h.p = cross(h.hx, h.hy);
    if (h.p.z == 0.0) {
        return false;
    }
    h.uv = h.p.xy / h.p.z;
    h.rho3 = dot(h.uv, h.uv);
    vec2 dd = mu - pix;
    h.rho2 = FILTER_INV_SQUARE * dot(dd, dd);
    h.g = exp(-0.5 * min(h.rho3, h.rho2));
    // z = Tw . (u, v, 1) = (Tw . p) / p_z, and Tw . (hx x hy) = Tw . (Tu x Tv)
    // is constant per splat: this form avoids the cancellation of the dot
    // product at grazing hits (f32).
    h.z = dot(tw, cross(tu, tv)) / h.p.z;
    return h.z >= NEAR && !isinf(h.z);
}

#endif
