#version 460
// Densification decision per Gaussian (method-notes §1.11):
//   grow (mean screen gradient >= threshold): clone when max scale <= dense
//   scale, else split into two; prune when opacity < opacity_min or, with
//   prune_big, screen radius > big_screen or max scale > big_world.
// Writes how many Gaussians each one becomes (0, 1 or 2; counts[n] = 0 so
// the exclusive scan ends in the new total) and its action
// (0 prune, 1 keep, 2 clone, 3 split).
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Opac { float opacity[]; };
layout(std430, binding = 1) readonly buffer Scales { vec2 log_scales[]; };
layout(std430, binding = 2) readonly buffer Accum { float accum[]; };
layout(std430, binding = 3) readonly buffer Denom { float denom[]; };
layout(std430, binding = 4) readonly buffer MaxR { float max_radii[]; };
layout(std430, binding = 5) writeonly buffer Counts { uint counts[]; };
layout(std430, binding = 6) writeonly buffer Action { uint action[]; };
layout(push_constant) uniform Push {
    uint n;
    uint grow;
    uint prune_big;
    uint pad;
    float grad_threshold;
    float dense_scale;
    float opacity_min;
    float big_world;
    float big_screen;
} pc;

bool pruned(float op, float smax, float radius) {
    bool bad = !(op >= pc.opacity_min) || isnan(smax) || isinf(smax);
    if (pc.prune_big != 0u) {
        bad = bad || radius > pc.big_screen || smax > pc.big_world;
    }
    return bad;
}

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i == pc.n) {
        counts[i] = 0u;
    }
    if (i >= pc.n) {
        return;
    }
    float d = denom[i];
    float g = d > 0.0 ? accum[i] / d : 0.0;
    float op = 1.0 / (1.0 + exp(-opacity[i]));
    vec2 ls = log_scales[i];
    float smax = exp(max(ls.x, ls.y));
    uint act = 1u;
    if (pc.grow != 0u && g >= pc.grad_threshold) {
        act = smax <= pc.dense_scale ? 2u : 3u;
    }
    uint cnt;
    if (act == 3u) {
        // Children are new (screen radius 0) and 1.6x smaller.
        cnt = pruned(op, smax / 1.6, 0.0) ? 0u : 2u;
    } else {
        cnt = pruned(op, smax, max_radii[i]) ? 0u : (act == 2u ? 2u : 1u);
    }
    counts[i] = cnt;
    action[i] = cnt == 0u ? 0u : act;
}
