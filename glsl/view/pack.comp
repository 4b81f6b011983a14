#version 460
// Planar f32 colour (R, G, B planes of n pixels) -> one packed 8-bit pixel
// per u32, quantised as tgs's PNGs are (clamp to [0, 1], x 255, rounded half
// away from zero; NaN and Inf as 0), in RGBA or BGRA byte order with alpha 255.
// With scale > 1 the planes are a frame `scale` times smaller on each side
// (sw pixels wide, sn in all) and each packed pixel (x, y) of the w-wide
// image shows plane pixel (x / scale, y / scale): a moving camera's frame.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Planes { float planes[]; };
layout(std430, binding = 1) writeonly buffer Packed { uint packed[]; };
layout(push_constant) uniform Push { uint n; uint bgra; uint w; uint scale; uint sw; uint sn; } pc;

uint q(float v) {
    if (isnan(v) || isinf(v)) {
        v = 0.0;
    }
    // `precise`: no fused multiply-add, so x 255 rounds as the host's f32 product does.
    precise float s = clamp(v, 0.0, 1.0) * 255.0;
    // Rounded from the exact fraction (floor(s + 0.5) would round 0.49999997 up).
    uint k = uint(s);
    return s - float(k) >= 0.5 ? k + 1 : k;
}

void main() {
    uint i = wg_linear() * WG + gl_LocalInvocationID.x;
    if (i >= pc.n) {
        return;
    }
    uint j = pc.scale == 1u ? i : ((i / pc.w) / pc.scale) * pc.sw + (i % pc.w) / pc.scale;
    uint r = q(planes[j]);
    uint g = q(planes[pc.sn + j]);
    uint b = q(planes[2 * pc.sn + j]);
    packed[i] = pc.bgra != 0 ? (b | (g << 8) | (r << 16) | (255u << 24)) : (r | (g << 8) | (b << 16) | (255u << 24));
}
