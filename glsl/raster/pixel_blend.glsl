// One front-to-back blending step of one pixel (method-notes §1.5) and the
// pixel's state in the output planes, shared by the two forward layouts
// (raster/forward.comp, raster/forward_sg.comp). The caller handles the CH
// feature channels itself. Expects the buffers `outp`, `fstate` and `ustate`
// (layouts in raster/forward.comp) to be declared before inclusion. With
// COLOUR_ONLY (a final image: tgs::embed, the viewer) only the transmittance
// and the contributors are kept: the features and alpha come out bit for
// bit as in the full forward, the depth, normal, median and distortion
// planes are not written (on llvmpipe the scattering set's forward takes
// ~25 ms less of the viewer's 400x300 frame; perf/journal, seventieth).
#ifndef TGS_RASTER_PIXEL_BLEND_GLSL
#define TGS_RASTER_PIXEL_BLEND_GLSL
#include "raster/common.glsl"

// A pixel's blending state: transmittance, depth numerator, normal, the two
// depth moments and the distortion, median depth and contributor, last
// contributor + 1, and whether it is saturated.
struct PixelState {
    float T, D, M1, M2, dist, med;
    vec3 N;
    uint last, med_i;
    bool done;
};

// Blend the splat of list index q with weight w = alpha T (returned) and
// transmittance Tn = T (1 - alpha) after it.
float blend(inout PixelState p, Hit h, float alpha, float Tn, vec3 nrm, uint q) {
    float T = p.T;
    float w = alpha * T;
#ifndef COLOUR_ONLY
    p.D += w * h.z;
    p.N += w * nrm;
    float m = ndc_depth(h.z);
    p.dist += w * (m * m * (1.0 - T) + p.M2 - 2.0 * m * p.M1);
    p.M1 += w * m;
    p.M2 += w * m * m;
    if (T > 0.5) {
        p.med = h.z;
        p.med_i = q;
    }
#endif
    p.T = Tn;
    p.last = q + 1u;
    return w;
}

// The state of pixel `px`: fresh, or carried over from the previous span pass.
PixelState load_pixel(uint px, bool inside, bool resume) {
    PixelState p = PixelState(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, vec3(0.0), 0u, 0xFFFFFFFFu, !inside);
    if (inside && resume) {
        uint plane = pc.width * pc.height;
#ifndef COLOUR_ONLY
        p.D = outp[P_DEPTH * plane + px];
        p.N = vec3(outp[P_NORMAL * plane + px], outp[(P_NORMAL + 1u) * plane + px], outp[(P_NORMAL + 2u) * plane + px]);
        p.med = outp[P_MEDIAN * plane + px];
        p.dist = outp[P_DIST * plane + px];
        p.M1 = fstate[plane + px];
        p.M2 = fstate[2u * plane + px];
#endif
        p.T = fstate[px];
        p.last = ustate[px];
        p.med_i = ustate[plane + px];
        p.done = ustate[2u * plane + px] != 0u;
    }
    return p;
}

// Write every plane of pixel `px` but the features (with COLOUR_ONLY, alpha).
void store_pixel(uint px, PixelState p) {
    uint plane = pc.width * pc.height;
    outp[P_ALPHA * plane + px] = 1.0 - p.T;
#ifndef COLOUR_ONLY
    outp[P_DEPTH * plane + px] = p.D;
    outp[P_NORMAL * plane + px] = p.N.x;
    outp[(P_NORMAL + 1u) * plane + px] = p.N.y;
    outp[(P_NORMAL + 2u) * plane + px] = p.N.z;
    outp[P_MEDIAN * plane + px] = p.med;
    outp[P_DIST * plane + px] = p.dist;
    fstate[plane + px] = p.M1;
    fstate[2u * plane + px] = p.M2;
#endif
    fstate[px] = p.T;
    ustate[px] = p.last;
    ustate[plane + px] = p.med_i;
    ustate[2u * plane + px] = p.done ? 1u : 0u;
}
#endif
