// The light field's Fourier features (mlp/encode.comp, mlp/fused_forward.comp):
// sin(pi a 2^k), cos(pi a 2^k) with the argument reduced exactly. 2^k a is
// exact in f32 and is reduced to t in [-1, 1] by subtracting an even integer
// (exact too), so sin(pi t) keeps f32 accuracy at L = 12 and |a| >= 1 where
// sin(2^11 pi a) would lose ~3 digits. One function for both kernels, so
// that their features are the same bits.
#ifndef TGS_MLP_ENCODING_GLSL
#define TGS_MLP_ENCODING_GLSL

const float PI = 3.14159265358979;

vec2 sincos_pi(float a, uint k) {
    float t = a * float(1u << k);
    t -= 2.0 * round(0.5 * t);
    return vec2(sin(PI * t), cos(PI * t));
}

#endif
