#version 460
// The light field's sample list (lightfield/common.glsl): after the
// exclusive scan of the per-pixel flags (R > threshold), every evaluated
// pixel writes its sample (x_refl normalized, w_r) at its rank and records
// the rank; the others record NONE. The last pixel writes the count (all
// evaluated pixels, even beyond the list's capacity max_samples: the host
// refuses such a view; ranks at or past it write nothing).
#include "lightfield/common.glsl"

layout(std430, binding = 1) readonly buffer Offsets { uint offsets[]; };
layout(std430, binding = 2) writeonly buffer SampleOf { uint sample_of[]; };
layout(std430, binding = 3) writeonly buffer Samples { float samples[]; };
layout(std430, binding = 4) writeonly buffer Count { uint count[]; };

void main() {
    uint pix = wg_linear() * WG + gl_LocalInvocationID.x;
    uint n = npix();
    if (pix >= n) {
        return;
    }
    bool on = evaluated(pix);
    uint o = offsets[pix];
    if (pix == n - 1u) {
        count[0] = o + (on ? 1u : 0u);
    }
    if (!on) {
        sample_of[pix] = NONE;
        return;
    }
    if (o >= pc.max_samples) {
        sample_of[pix] = NONE;
        return;
    }
    sample_of[pix] = o;
    vec3 ray = pixel_ray(pix);
    // R > threshold >= 0 implies alpha > 0 (R <= alpha).
    float z = refl_plane(CH + 1u, pix) / max(refl_plane(CH, pix), F0_EPS);
    vec3 xv = ray * z;
    vec3 t = vec3(pc.rot[0].w, pc.rot[1].w, pc.rot[2].w);
    vec3 xw = to_world_dir(xv - t);
    vec3 xn = (xw - pc.centre.xyz) * pc.scale.xyz;
    vec3 d = normalize(ray);
    vec3 N = blended_normal(pix);
    float len = length(N);
    // Without a normal the ray goes back to the camera.
    vec3 r = len > NORMAL_EPS ? reflect(d, N / len) : -d;
    vec3 w = normalize(to_world_dir(r));
    samples[6u * o] = xn.x;
    samples[6u * o + 1u] = xn.y;
    samples[6u * o + 2u] = xn.z;
    samples[6u * o + 3u] = w.x;
    samples[6u * o + 4u] = w.y;
    samples[6u * o + 5u] = w.z;
}
