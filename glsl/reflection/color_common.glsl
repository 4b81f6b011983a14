// Per-Gaussian reflection colour (paper eq. per_gauss_color, method-notes
// §3.4): v = normalize(camera - p), n = t_w flipped to face the camera,
// w = 2 (n.v) n - v, c = f0 * E(w) (or E(w) alone when the deferred pass
// applies Schlick with the blended F0). Rasterized features per Gaussian:
// [c (3), r, f0 (3, only with CH = 7)]. Material (the trainable block,
// 4 floats per Gaussian): raw f0 (3), raw r (sigmoid activations).
#ifndef TGS_COLOR_COMMON_GLSL
#define TGS_COLOR_COMMON_GLSL
#include "common.glsl"

layout(push_constant) uniform Push {
    uint n;        // Gaussians
    uint channels; // rasterized features: 4 (c, r) or 7 (c, r, f0)
    uint res;      // cube face size
    uint schlick;  // 1: c = E(w) (Fresnel applied per pixel); 0: c = f0 E(w)
    vec3 centre;   // camera centre, world space
    uint depth_iters; // > 0: the proxy's radius per direction from the depth map, this many refinements
    vec4 proxy;    // the map's parallax proxy: centre (xyz), radius (w; 0: infinitely far)
} pc;

// Camera-facing world normal t_w of a normalized quaternion (r, x, y, z).
vec3 quat_normal(vec4 q) {
    float r = q.x, x = q.y, y = q.z, z = q.w;
    return vec3(2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y));
}

struct ReflGeom {
    vec4 q;      // normalized quaternion (0 when degenerate)
    float qlen;  // |q_raw|
    vec3 v;      // unit direction to the camera
    float vlen;  // |camera - p|
    vec3 n;      // unit normal facing the camera
    float sgn;   // n = sgn * t_w
    vec3 w;      // mirror direction
};

ReflGeom refl_geom(vec3 p, vec4 q_raw) {
    ReflGeom g;
    float qq = dot(q_raw, q_raw);
    g.qlen = sqrt(qq);
    g.q = (qq > 1e-30 && !isinf(qq)) ? q_raw / g.qlen : vec4(0.0);
    vec3 t = quat_normal(g.q);
    vec3 dv = pc.centre - p;
    g.vlen = length(dv);
    g.v = g.vlen > 1e-20 ? dv / g.vlen : vec3(0.0, 0.0, 1.0);
    g.sgn = dot(t, g.v) < 0.0 ? -1.0 : 1.0;
    g.n = g.sgn * t;
    g.w = 2.0 * dot(g.n, g.v) * g.n - g.v;
    return g;
}

// The cube-map lookup direction of a reflection from p along the unit
// mirror direction w. With a parallax proxy (radius R > 0) and p inside
// it, the map holds the light of the sphere |x - c| = R (a local cube
// map): the lookup goes from c to where p + t w (t > 0) leaves the sphere,
// d = o + t w with o = p - c, t = s - b, b = o.w, s = sqrt(b^2 - |o|^2 + R^2)
// (s > |b| inside, so t > 0). Otherwise d = w. d is not unit length (the
// cube lookup does not need it).
//
// With a depth map (pc.depth_iters > 0: the distance from c to the scene
// along each texel's direction, `env_depth[]`), the light lies on the
// scene's surface seen from c, not on one sphere: R is the depth the map
// gives in the current lookup direction, starting from w's own (light at
// infinity) and refined depth_iters times (each step intersects the
// sphere of that radius; a step whose sphere does not hold p keeps the
// previous direction). The backward differentiates the last step with its
// radius held fixed (env_dir_backward).
struct EnvDir {
    vec3 d;
    bool on;
    vec3 o;
    float t, b, s;
};

// The bilinear depth of the map in direction d.
float env_depth_at(vec3 d);

// One intersection with the sphere of radius r around the proxy's centre:
// false (e unchanged) when p is not inside it.
bool env_sphere(vec3 o, vec3 w, float r, inout EnvDir e) {
    float k = dot(o, o) - r * r;
    if (!(k < 0.0)) {
        return false;
    }
    e.on = true;
    e.o = o;
    e.b = dot(o, w);
    e.s = sqrt(e.b * e.b - k);
    e.t = e.s - e.b;
    e.d = o + e.t * w;
    return true;
}

EnvDir env_dir(vec3 p, vec3 w) {
    EnvDir e;
    e.d = w;
    e.on = false;
    e.o = vec3(0.0);
    e.t = 0.0;
    e.b = 0.0;
    e.s = 1.0;
    float r = pc.proxy.w;
    if (r > 0.0) {
        vec3 o = p - pc.proxy.xyz;
        if (pc.depth_iters == 0u) {
            env_sphere(o, w, r, e);
        } else {
            for (uint k = 0u; k < pc.depth_iters; k++) {
                if (!env_sphere(o, w, env_depth_at(e.d), e)) {
                    break;
                }
            }
        }
    }
    return e;
}

// From dL/dd to dL/dw (returned) and dL/dp (added to dp).
vec3 env_dir_backward(EnvDir e, vec3 w, vec3 dd, inout vec3 dp) {
    if (!e.on) {
        return dd;
    }
    float dw_t = dot(dd, w); // dL/dt
    // dt/dw = (b / s - 1) o; dt/do = (b w - o) / s - w.
    dp += dd + dw_t * ((e.b * w - e.o) / e.s - w);
    return e.t * dd + dw_t * (e.b / e.s - 1.0) * e.o;
}

float sigmoid(float x) {
    return 1.0 / (1.0 + exp(-x));
}

layout(std430, binding = 0) readonly buffer Means { float means[]; };
layout(std430, binding = 1) readonly buffer Quats { vec4 quats[]; };
layout(std430, binding = 2) readonly buffer Material { float material[]; };
layout(std430, binding = 3) readonly buffer Env { float env[]; };
#include "reflection/envmap.glsl"
// The distance from the proxy's centre to the scene per texel (read only
// when pc.depth_iters > 0; the kernel binds a placeholder otherwise).
layout(std430, binding = ENV_DEPTH_BINDING) readonly buffer EnvDepth { float env_depth[]; };

float env_depth_at(vec3 d) {
    EnvTaps t = env_taps(d, pc.res);
    float z = 0.0;
    for (uint k = 0u; k < 4u; k++) {
        z += t.w[k] * env_depth[t.idx[k]];
    }
    return z;
}

vec3 gaussian_mean(uint i) {
    return vec3(means[3u * i], means[3u * i + 1u], means[3u * i + 2u]);
}
// Activated f0 (3) and r of Gaussian i.
vec3 gaussian_f0(uint i) {
    return vec3(sigmoid(material[4u * i]), sigmoid(material[4u * i + 1u]), sigmoid(material[4u * i + 2u]));
}
float gaussian_r(uint i) {
    return sigmoid(material[4u * i + 3u]);
}

#endif
