#version 460
// Forward of the per-Gaussian reflection colour (color_common.glsl): one
// invocation per Gaussian writes its rasterized features.
#include "reflection/color_common.glsl"

layout(std430, binding = 0) readonly buffer Means { float means[]; };
layout(std430, binding = 1) readonly buffer Quats { vec4 quats[]; };
layout(std430, binding = 2) readonly buffer Material { float material[]; };
layout(std430, binding = 3) readonly buffer Env { float env[]; };
layout(std430, binding = 4) writeonly buffer Feat { float feat[]; };
#include "reflection/envmap.glsl"

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    vec3 p = vec3(means[3u * i], means[3u * i + 1u], means[3u * i + 2u]);
    ReflGeom g = refl_geom(p, quats[i]);
    vec3 e = sigmoid3(env_raw(env_taps(g.w, pc.res)));
    vec3 f0 = vec3(sigmoid(material[4u * i]), sigmoid(material[4u * i + 1u]), sigmoid(material[4u * i + 2u]));
    float r = sigmoid(material[4u * i + 3u]);
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
