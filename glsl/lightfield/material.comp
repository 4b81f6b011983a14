#version 460
// The reflection set's rasterized features in Stage III: the sigmoid of its
// material [f0 (3), r] per Gaussian (forward), and the material gradient
// d_mat = d_feat s (1 - s) (backward, overwritten).
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Mat { float mat[]; };
layout(std430, binding = 1) buffer Feat { float feat[]; };
layout(std430, binding = 2) buffer DMat { float dmat[]; };
layout(push_constant) uniform Push {
    uint n;         // floats (4 per Gaussian)
    uint backward;  // 0: feat = sigmoid(mat); 1: dmat = feat_grad s (1 - s)
} pc;

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    float s = 1.0 / (1.0 + exp(-mat[i]));
    if (pc.backward == 0u) {
        feat[i] = s;
    } else {
        dmat[i] = feat[i] * s * (1.0 - s);
    }
}
