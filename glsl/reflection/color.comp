#version 460
// Forward of the per-Gaussian reflection colour (color_common.glsl): one
// invocation per Gaussian writes its rasterized features.
#define ENV_DEPTH_BINDING 5
#include "reflection/color_common.glsl"

layout(std430, binding = 4) writeonly buffer Feat { float feat[]; };

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    vec3 p = gaussian_mean(i);
    ReflGeom g = refl_geom(p, quats[i]);
    vec3 e = sigmoid3(env_raw(env_taps(env_dir(p, g.w).d, pc.res)));
    vec3 f0 = gaussian_f0(i);
    float r = gaussian_r(i);
    vec3 c = pc.schlick != 0u ? e : f0 * e;
    uint b = pc.channels * i;
    feat[b] = c.x;
    feat[b + 1u] = c.y;
    feat[b + 2u] = c.z;
    feat[b + 3u] = r;
    if (pc.channels == 7u) {
        feat[b + 4u] = f0.x;
        feat[b + 5u] = f0.y;
        feat[b + 6u] = f0.z;
    }
}
