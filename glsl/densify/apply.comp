#version 460
// Writes the densified copy of one per-Gaussian array (`width` floats per
// Gaussian) at the scanned offsets. Modes:
//   0 Adam moments: kept Gaussians keep theirs, new ones (the clone's copy,
//     split children) start at zero;
//   1 plain copy to every output;
//   2 means: split children at p + R (s_u xi_1, s_v xi_2, 0), xi ~ N(0, 1)
//     from a counter-based hash of (seed, Gaussian, child): deterministic;
//   3 log-scales: split children get log(s / 1.6).
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Src { float src[]; };
layout(std430, binding = 1) writeonly buffer Dst { float dst[]; };
layout(std430, binding = 2) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 3) readonly buffer Action { uint action[]; };
layout(std430, binding = 4) readonly buffer Scales { vec2 log_scales[]; };
layout(std430, binding = 5) readonly buffer Quats { vec4 quats[]; };
// Sources [src_base, n): an array too large for one binding is copied in
// slices (pipelines/src/train/densify.rs copy_slice), the source bound
// from Gaussian src_base and the destination from float dst_origin; both
// 0 for a whole copy.
layout(push_constant) uniform Push { uint n; uint width; uint mode; uint seed; uint src_base; uint dst_origin; } pc;

uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

float unit(uint h) {
    return (float(h >> 8u) + 0.5) * (1.0 / 16777216.0);
}

vec2 gauss2(uint i, uint child) {
    uint h1 = pcg(pc.seed ^ pcg(i * 2u + child));
    uint h2 = pcg(h1 ^ 0x9E3779B9u);
    float r = sqrt(-2.0 * log(unit(h1)));
    float t = 6.283185307179586 * unit(h2);
    return r * vec2(cos(t), sin(t));
}

mat3 rotation(vec4 q) {
    q = q / max(length(q), 1e-12);
    float r = q.x, x = q.y, y = q.z, z = q.w;
    return mat3(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + r * z), 2.0 * (x * z - r * y),
        2.0 * (x * y - r * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + r * x),
        2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y));
}

void main() {
    uint i = pc.src_base + wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    uint si = i - pc.src_base;
    uint o = offsets[i];
    uint cnt = offsets[i + 1u] - o;
    uint act = action[i];
    for (uint k = 0u; k < cnt; k++) {
        bool fresh = act == 3u || (act == 2u && k == 1u);
        if (pc.mode == 2u && act == 3u) {
            vec2 s = exp(log_scales[i]);
            vec2 xi = gauss2(i, k);
            vec3 d = rotation(quats[i]) * vec3(s * xi, 0.0);
            for (uint j = 0u; j < 3u; j++) {
                dst[(o + k) * 3u + j - pc.dst_origin] = src[si * 3u + j] + d[j];
            }
            continue;
        }
        for (uint j = 0u; j < pc.width; j++) {
            float v = src[si * pc.width + j];
            if (pc.mode == 0u && fresh) {
                v = 0.0;
            } else if (pc.mode == 3u && act == 3u) {
                v -= 0.47000362924573558;  // log(1.6)
            }
            dst[(o + k) * pc.width + j - pc.dst_origin] = v;
        }
    }
}
