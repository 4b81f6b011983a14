#version 460
// TSDF fusion of one view (`tgs mesh`, harness/src/mesh): one invocation
// per voxel of a regular grid, which it updates with the view's depth at
// the pixel its centre projects to (nearest pixel; pixel centres at
// integer coordinates, as the rasterizer's). With z the voxel centre's
// view depth and d the pixel's depth (a surface's median depth):
//   sdf = d - z; skipped where the pixel has no depth (d <= 0, NaN or
//   infinite), d is past
//   depth_max, the pixel's weight w is 0, or sdf < -trunc (hidden);
//   t = min(sdf / trunc, 1);
//   T <- (T W + t w) / (W + w), colour likewise, W <- W + w.
// Each voxel has one writer and the views come in a fixed order, so the
// grid is the same, bit for bit, at any subgroup size or schedule; no
// atomics. The f64 reference is tests/src/tsdf_ref.rs.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Depth { float depth[]; };
layout(std430, binding = 1) readonly buffer PixWeight { float pix_weight[]; };
// Colour planes [r (npix), g (npix), b (npix)].
layout(std430, binding = 2) readonly buffer Colour { float colour[]; };
layout(std430, binding = 3) buffer Tsdf { float tsdf[]; };
layout(std430, binding = 4) buffer Wsum { float wsum[]; };
layout(std430, binding = 5) buffer Red { float red[]; };
layout(std430, binding = 6) buffer Green { float green[]; };
layout(std430, binding = 7) buffer Blue { float blue[]; };

layout(push_constant) uniform Push {
    vec4 rot[3];    // world_to_view rows: xyz = R row, w = t
    float fx, fy, cx, cy;
    vec4 origin;    // xyz: the grid's corner; w: the voxel size
    uvec4 dims;     // xyz: voxels per axis; w: image width
    uint height;
    float trunc;
    float depth_max;
    uint pad;
} pc;

void main() {
    uint v = wg_linear() * WG + gl_LocalInvocationID.x;
    uint nx = pc.dims.x, ny = pc.dims.y, nz = pc.dims.z;
    if (v >= nx * ny * nz) {
        return;
    }
    uint i = v % nx, j = (v / nx) % ny, k = v / (nx * ny);
    vec3 p = pc.origin.xyz + (vec3(i, j, k) + 0.5) * pc.origin.w;
    vec3 q = vec3(dot(pc.rot[0].xyz, p) + pc.rot[0].w, dot(pc.rot[1].xyz, p) + pc.rot[1].w, dot(pc.rot[2].xyz, p) + pc.rot[2].w);
    float z = q.z;
    if (!(z > 1e-6)) {
        return;
    }
    float u = pc.fx * q.x / z + pc.cx;
    float w = pc.fy * q.y / z + pc.cy;
    float width = float(pc.dims.w), height = float(pc.height);
    // Nearest pixel: the one whose centre (integer coordinates) is within
    // half a pixel; NaN fails every comparison.
    if (!(u >= -0.5 && u < width - 0.5 && w >= -0.5 && w < height - 0.5)) {
        return;
    }
    uint px = min(uint(floor(u + 0.5)), pc.dims.w - 1u);
    uint py = min(uint(floor(w + 0.5)), pc.height - 1u);
    uint pix = py * pc.dims.w + px;
    float d = depth[pix];
    float wt = pix_weight[pix];
    if (!(d > 0.0 && d <= pc.depth_max && !isinf(d) && wt > 0.0)) {
        return;
    }
    float sdf = d - z;
    if (sdf < -pc.trunc) {
        return;
    }
    float t = min(sdf / pc.trunc, 1.0);
    uint npix = pc.dims.w * pc.height;
    float W = wsum[v];
    float W2 = W + wt;
    tsdf[v] = (tsdf[v] * W + t * wt) / W2;
    red[v] = (red[v] * W + colour[pix] * wt) / W2;
    green[v] = (green[v] * W + colour[npix + pix] * wt) / W2;
    blue[v] = (blue[v] * W + colour[2u * npix + pix] * wt) / W2;
    wsum[v] = W2;
}
