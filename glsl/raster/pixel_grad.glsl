// One pixel's share of one splat's gradient (method-notes §1.7), shared by
// the two backward layouts (raster/backward.comp, raster/backward_sg.comp).
// Back to front: given the hit, the splat's alpha at the pixel, the pixel's
// transmittance T and suffix sum S after the splat, and V (every output's
// value for the splat combined with its upstream gradient), returns the
// record's geometric entries, the blending weight w and dL/dV's factor, and
// steps T and S back past the splat:
//   dL/dalpha = T_i V - S / (1 - alpha),  S += w V,  T_i = T / (1 - alpha).
#ifndef TGS_RASTER_PIXEL_GRAD_GLSL
#define TGS_RASTER_PIXEL_GRAD_GLSL
#include "raster/common.glsl"

struct PixelRec {
    vec3 dTu, dTv, dTw, dn;
    vec2 dmu;
    float dO, w;
};

// `m` is ndc_depth(h.z); gD, gDist, gMed, gN the pixel's upstream gradients
// of depth, distortion, median depth and normal; A, M1 its final alpha and
// first depth moment; `median` whether this splat is the pixel's median.
PixelRec pixel_grad(Hit h, float alpha, float op, vec3 tw, vec2 mu, vec2 pf, float V, float m,
                    float gD, float gDist, float gMed, vec3 gN, float A, float M1, bool median,
                    inout float T, inout float S) {
    const float DMDZ = FAR * NEAR / (FAR - NEAR);
    PixelRec r;
    float Ti = T / (1.0 - alpha);
    r.w = alpha * Ti;
    float dAlpha = Ti * V - S / (1.0 - alpha);
    S += r.w * V;
    T = Ti;
    float dz = r.w * gD + gDist * 2.0 * r.w * (m * A - M1) * DMDZ / (h.z * h.z) + (median ? gMed : 0.0);
    bool clamped = op * h.g > ALPHA_MAX;
    float dG = clamped ? 0.0 : op * dAlpha;
    r.dO = clamped ? 0.0 : h.g * dAlpha;
    bool branch3 = h.rho3 <= h.rho2;
    // z = Tw . (u, v, 1) depends on (u, v) in both branches.
    vec2 gu = dz * tw.xy + (branch3 ? -dG * h.g * h.uv : vec2(0.0));
    vec3 dp = vec3(gu / h.p.z, -(gu.x * h.uv.x + gu.y * h.uv.y) / h.p.z);
    vec3 dhx = cross(h.hy, dp);
    vec3 dhy = cross(dp, h.hx);
    r.dTu = -dhx;
    r.dTv = -dhy;
    r.dTw = pf.x * dhx + pf.y * dhy + dz * vec3(h.uv, 1.0);
    r.dmu = branch3 ? vec2(0.0) : -dG * h.g * FILTER_INV_SQUARE * (mu - pf);
    r.dn = r.w * gN;
    return r;
}
#endif
