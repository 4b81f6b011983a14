// The per-Gaussian 2DGS projection (method-notes §1.3), shared by the
// forward projection and the per-Gaussian backward. Expects a float buffer
// `cam` (layout in raster/common.glsl) to be declared before inclusion, or
// a macro CAM(i) that reads its float i.
#ifndef TGS_RASTER_PROJECT_GLSL
#define TGS_RASTER_PROJECT_GLSL
#ifndef CAM
#define CAM(at) cam[at]
#endif
#include "raster/common.glsl"

vec3 cam_row(uint i) {
    return vec3(CAM(4u * i), CAM(4u * i + 1u), CAM(4u * i + 2u));
}
// World -> view rotation applied to v, and its transpose.
vec3 view_rot(vec3 v) {
    return vec3(dot(cam_row(0u), v), dot(cam_row(1u), v), dot(cam_row(2u), v));
}
vec3 view_rot_t(vec3 v) {
    return cam_row(0u) * v.x + cam_row(1u) * v.y + cam_row(2u) * v.z;
}
vec3 view_t() {
    return vec3(CAM(3), CAM(7), CAM(11));
}
vec4 intrinsics() {
    return vec4(CAM(12), CAM(13), CAM(14), CAM(15));
}
vec3 cam_centre() {
    return vec3(CAM(16), CAM(17), CAM(18));
}

struct Proj {
    Splat s;
    mat3 rot;    // world rotation, columns t_u t_v t_w
    vec2 scale;
    vec3 pv;     // centre in view space
    float sgn;   // +1 or -1: normal flipped to face the camera
    float d;     // sum(t * Tw * Tw) with t = (9, 9, -1)
    vec3 f;      // t / d
    float radius;
};

bool finite3(vec3 v) {
    return !any(isnan(v)) && !any(isinf(v));
}

// Returns false (culled) for degenerate quaternions, centres at or in front
// of the near plane, edge-on normals with zero cosine, a singular bounding
// conic, or any non-finite result.
bool project(vec3 p, vec2 log_s, vec4 q_raw, float o_raw, out Proj pr) {
    pr.s.o = 1.0 / (1.0 + exp(-o_raw));
    float qq = dot(q_raw, q_raw);
    if (!(qq > 1e-30) || isinf(qq)) {
        return false;
    }
    vec4 q = q_raw * inversesqrt(qq);
    pr.rot = quat_to_rot(q);
    pr.scale = exp(log_s);
    pr.pv = view_rot(p) + view_t();
    if (!(pr.pv.z > NEAR)) {
        return false;
    }
    vec3 au = view_rot(pr.scale.x * pr.rot[0]);
    vec3 av = view_rot(pr.scale.y * pr.rot[1]);
    vec4 k = intrinsics();
    pr.s.tu = vec3(k.x * au.x + k.z * au.z, k.x * av.x + k.z * av.z, k.x * pr.pv.x + k.z * pr.pv.z);
    pr.s.tv = vec3(k.y * au.y + k.w * au.z, k.y * av.y + k.w * av.z, k.y * pr.pv.y + k.w * pr.pv.z);
    pr.s.tw = vec3(au.z, av.z, pr.pv.z);
    vec3 nv = view_rot(pr.rot[2]);
    float cosv = -dot(pr.pv, nv);
    if (cosv == 0.0 || isnan(cosv)) {
        return false;
    }
    pr.sgn = cosv < 0.0 ? -1.0 : 1.0;
    pr.s.n = pr.sgn * nv;
    const vec3 t = vec3(CUTOFF * CUTOFF, CUTOFF * CUTOFF, -1.0);
    pr.d = dot(t, pr.s.tw * pr.s.tw);
    if (pr.d == 0.0) {
        return false;
    }
    pr.f = t / pr.d;
    pr.s.mu = vec2(dot(pr.f, pr.s.tu * pr.s.tw), dot(pr.f, pr.s.tv * pr.s.tw));
    vec2 ext = sqrt(max(vec2(1e-4), pr.s.mu * pr.s.mu - vec2(dot(pr.f, pr.s.tu * pr.s.tu), dot(pr.f, pr.s.tv * pr.s.tv))));
    pr.radius = ceil(max(max(ext.x, ext.y), CUTOFF * FILTER_SIZE));
    return finite3(pr.s.tu) && finite3(pr.s.tv) && finite3(pr.s.tw) && finite3(vec3(pr.s.mu, pr.radius)) && finite3(pr.s.n);
}

// Pixel-space bounds (lo.x, lo.y, hi.x, hi.y) of where the splat's alpha
// o G can reach ALPHA_MIN, per axis (the blend skips every other pixel):
// G = exp(-rho / 2) >= ALPHA_MIN / o needs rho <= k^2 = 2 ln(o / ALPHA_MIN),
// and rho = min(rho3, rho2) is below k^2 inside the splat-plane ellipse
// u^2 + v^2 <= k^2 (its screen box from the dual conic with t = (k^2, k^2,
// -1), about its own centre) or inside the low-pass disc of radius
// k / sqrt(FILTER_INV_SQUARE) about mu. So k is 3.33 at full opacity and
// shrinks with it; o < ALPHA_MIN gives an empty box. An ellipse that reaches
// the camera plane (d >= 0: unbounded on screen) can reach any pixel, so its
// bounds are the whole plane (`bounded` false; so are bounds that are not
// finite): such a splat is binned to every tile. (Its 3-sigma square, used
// before, missed pixels it reaches and made the image depend on the tile
// size: tests/tests/raster_hard.rs `pixel_boxes_hold_every_reached_pixel`.)
vec4 pixel_bounds_of(Proj pr, out bool bounded) {
    bounded = true;
    float a = pr.s.o / ALPHA_MIN;
    if (!(a >= 1.0)) {
        return vec4(1.0, 1.0, 0.0, 0.0);
    }
    float k2 = 2.0 * log(a);
    vec3 t = vec3(k2, k2, -1.0);
    float d = dot(t, pr.s.tw * pr.s.tw);
    if (d < 0.0) {
        vec3 f = t / d;
        vec2 c = vec2(dot(f, pr.s.tu * pr.s.tw), dot(f, pr.s.tv * pr.s.tw));
        vec2 e = sqrt(max(vec2(0.0), c * c - vec2(dot(f, pr.s.tu * pr.s.tu), dot(f, pr.s.tv * pr.s.tv))));
        float r2 = sqrt(k2 / FILTER_INV_SQUARE);
        vec4 b = vec4(min(c - e, pr.s.mu - r2), max(c + e, pr.s.mu + r2));
        if (!any(isnan(b)) && !any(isinf(b))) {
            return b;
        }
    }
    bounded = false;
    return vec4(-3.0e38, -3.0e38, 3.0e38, 3.0e38);
}

// The pixels a tile kernel evaluates the splat at (see `in_box` in
// raster/common.glsl): the bounds above widened by one pixel on each side,
// so that f32 rounding of the bounds never drops a pixel whose alpha
// reaches ALPHA_MIN; every pixel when the splat is unbounded on screen.
vec4 pixel_box(vec4 b, bool bounded) {
    return bounded ? b + vec4(-1.0, -1.0, 1.0, 1.0) : vec4(-3.0e38, -3.0e38, 3.0e38, 3.0e38);
}

// Tile rectangle [x0, x1) x [y0, y1) of the pixels (centres at integers)
// inside pixel bounds b, clamped to the grid; empty when no pixel is.
uvec4 tile_rect(vec4 b) {
    vec2 first = ceil(b.xy);
    vec2 last = floor(b.zw);
    if (any(greaterThan(first, last))) {
        return uvec4(0u);
    }
    vec2 grid = vec2(pc.tiles_x, pc.tiles_y);
    vec2 lo = clamp(floor(first / float(TILE)), vec2(0.0), grid);
    vec2 hi = clamp(floor(last / float(TILE)) + 1.0, vec2(0.0), grid);
    return uvec4(uvec2(lo), uvec2(hi));
}
#endif
