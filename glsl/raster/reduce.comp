#version 460
// variant: RECORDS_BDA
// variant: ADAM
// variant: ADAM RECORDS_BDA
// variant: ADAM COLOUR_ONLY
// variant: ADAM COLOUR_ONLY RECORDS_BDA
// variant: ADAM TEXEL
// variant: ADAM COLOUR_ONLY TEXEL
#ifdef RECORDS_BDA
#extension GL_EXT_buffer_reference : require
#extension GL_EXT_buffer_reference_uvec2 : require
#endif
// One invocation per depth-ranked Gaussian r: sums its intersection records
// RECORDS[offsets[r] .. offsets[r+1]) in index order (fixed order, no atomics),
// then applies the projection backward (method-notes §1.7, per-Gaussian
// part) and writes the Gaussian's parameter gradients (overwriting), plus
// the screen-space gradient used by densification (in NDC units, as 3DGS).
// Variant ADAM steps the Gaussian's parameters with Adam instead of writing
// its gradients (bindings 9-13 then hold the first moments, 15-19 the
// second ones; adam/step.comp's arithmetic, so the result is the same as this
// kernel followed by adam/step.comp): one pass over the parameters fewer.
// ADAM COLOUR_ONLY (after the COLOUR_ONLY tile backward, for a set whose
// geometry does not train): sums the feature records alone and steps the
// features alone; means, scales, rotations, opacity and their moments are
// left as they are, densification gradients are written as zero.
// ADAM TEXEL (CPU devices): every input read as a uniform texel buffer,
// which llvmpipe fetches as one gather where it loads a storage buffer lane
// by lane (perf/RESULTS.md, forty-first entry): the camera (0), the ids (6),
// offsets (7) and records (8, the records buffer itself), and the
// parameters and moments through views 20-34 of the storage buffers 1-5,
// 9-13 and 15-19 that the step writes. The same arithmetic. It writes a
// Gaussian's features and their moments four at a time where they come in
// fours (a store is a loop over the lanes on llvmpipe, whatever its width;
// the reduce about a tenth faster, perf/RESULTS.md, forty-ninth entry).
#include "common.glsl"

#ifdef ADAM
#define PARAM_ACCESS
#else
#define PARAM_ACCESS readonly
#endif
#ifdef TEXEL
layout(binding = 0) uniform samplerBuffer cam_t;
#define CAM(at) texelFetch(cam_t, int(at)).r
#else
layout(std430, binding = 0) readonly buffer Cam { float cam[]; };
#endif
layout(std430, binding = 1) PARAM_ACCESS buffer Means { float means[]; };
layout(std430, binding = 2) PARAM_ACCESS buffer Scales { float log_scales[]; };
layout(std430, binding = 3) PARAM_ACCESS buffer Quats { vec4 quats[]; };
layout(std430, binding = 4) PARAM_ACCESS buffer Opac { float opacity[]; };
#if defined(ADAM) && defined(TEXEL)
// Read through views 24, 29 and 34; written four features at a time where
// a Gaussian's features come in fours (FEAT4 below).
layout(std430, binding = 5) writeonly buffer Feats { vec4 feats4[]; };
#define W_FEATS(i) feats4[(i) >> 2u][(i) & 3u]
#define W_M1_FEATS(i) m1_feats4[(i) >> 2u][(i) & 3u]
#define W_M2_FEATS(i) m2_feats4[(i) >> 2u][(i) & 3u]
#define FEAT4
#else
layout(std430, binding = 5) PARAM_ACCESS buffer Feats { float feats[]; };
#define W_FEATS(i) feats[i]
#define W_M1_FEATS(i) m1_feats[i]
#define W_M2_FEATS(i) m2_feats[i]
#endif
#ifdef TEXEL
layout(binding = 6) uniform usamplerBuffer ids_t;
layout(binding = 7) uniform usamplerBuffer offsets_t;
layout(binding = 8) uniform samplerBuffer records_t;
layout(binding = 20) uniform samplerBuffer means_t;
layout(binding = 21) uniform samplerBuffer scales_t;
layout(binding = 22) uniform samplerBuffer quats_t;
layout(binding = 23) uniform samplerBuffer opacity_t;
layout(binding = 24) uniform samplerBuffer feats_t;
layout(binding = 25) uniform samplerBuffer m1_means_t;
layout(binding = 26) uniform samplerBuffer m1_scales_t;
layout(binding = 27) uniform samplerBuffer m1_quats_t;
layout(binding = 28) uniform samplerBuffer m1_opacity_t;
layout(binding = 29) uniform samplerBuffer m1_feats_t;
layout(binding = 30) uniform samplerBuffer m2_means_t;
layout(binding = 31) uniform samplerBuffer m2_scales_t;
layout(binding = 32) uniform samplerBuffer m2_quats_t;
layout(binding = 33) uniform samplerBuffer m2_opacity_t;
layout(binding = 34) uniform samplerBuffer m2_feats_t;
#define TX(t, at) texelFetch(t, int(at)).r
#define IDS(at) texelFetch(ids_t, int(at)).r
#define OFFSETS(at) texelFetch(offsets_t, int(at)).r
#define REC(at) TX(records_t, at)
#define R_MEANS(at) TX(means_t, at)
#define R_LOG_SCALES(at) TX(scales_t, at)
#define R_QUAT(at) vec4(TX(quats_t, 4u * (at)), TX(quats_t, 4u * (at) + 1u), TX(quats_t, 4u * (at) + 2u), TX(quats_t, 4u * (at) + 3u))
#define R_OPACITY(at) TX(opacity_t, at)
#define R_FEATS(at) TX(feats_t, at)
#define R_M1_MEANS(at) TX(m1_means_t, at)
#define R_M1_SCALES(at) TX(m1_scales_t, at)
#define R_M1_QUATS(at) TX(m1_quats_t, at)
#define R_M1_OPACITY(at) TX(m1_opacity_t, at)
#define R_M1_FEATS(at) TX(m1_feats_t, at)
#define R_M2_MEANS(at) TX(m2_means_t, at)
#define R_M2_SCALES(at) TX(m2_scales_t, at)
#define R_M2_QUATS(at) TX(m2_quats_t, at)
#define R_M2_OPACITY(at) TX(m2_opacity_t, at)
#define R_M2_FEATS(at) TX(m2_feats_t, at)
#else
layout(std430, binding = 6) readonly buffer Ids { uint ids[]; };
layout(std430, binding = 7) readonly buffer Offsets { uint offsets[]; };
#define RECORDS_BINDING 8
#define RECORDS_ACCESS readonly
#include "raster/records.glsl"
#define IDS(at) ids[at]
#define OFFSETS(at) offsets[at]
#define REC(at) RECORDS[at]
#define R_MEANS(at) means[at]
#define R_LOG_SCALES(at) log_scales[at]
#define R_QUAT(at) quats[at]
#define R_OPACITY(at) opacity[at]
#define R_FEATS(at) feats[at]
#define R_M1_MEANS(at) m1_means[at]
#define R_M1_SCALES(at) m1_scales[at]
#define R_M1_QUATS(at) m1_quats[at]
#define R_M1_OPACITY(at) m1_opacity[at]
#define R_M1_FEATS(at) m1_feats[at]
#define R_M2_MEANS(at) m2_means[at]
#define R_M2_SCALES(at) m2_scales[at]
#define R_M2_QUATS(at) m2_quats[at]
#define R_M2_OPACITY(at) m2_opacity[at]
#define R_M2_FEATS(at) m2_feats[at]
#endif
layout(std430, binding = 14) writeonly buffer Densify { vec2 densify[]; };

#include "raster/project.glsl"

#ifdef ADAM
layout(std430, binding = 9) buffer M1Means { float m1_means[]; };
layout(std430, binding = 10) buffer M1Scales { float m1_scales[]; };
layout(std430, binding = 11) buffer M1Quats { float m1_quats[]; };
layout(std430, binding = 12) buffer M1Opac { float m1_opacity[]; };
#ifdef FEAT4
layout(std430, binding = 13) writeonly buffer M1Feats { vec4 m1_feats4[]; };
#else
layout(std430, binding = 13) buffer M1Feats { float m1_feats[]; };
#endif
layout(std430, binding = 15) buffer M2Means { float m2_means[]; };
layout(std430, binding = 16) buffer M2Scales { float m2_scales[]; };
layout(std430, binding = 17) buffer M2Quats { float m2_quats[]; };
layout(std430, binding = 18) buffer M2Opac { float m2_opacity[]; };
#ifdef FEAT4
layout(std430, binding = 19) writeonly buffer M2Feats { vec4 m2_feats4[]; };
#else
layout(std430, binding = 19) buffer M2Feats { float m2_feats[]; };
#endif

// adam/step.comp's step of parameter P with moments M, V (written; read as
// PR, MR, VR), gradient G, rate LR.
#define ADAM_STEP(P, M, V, PR, MR, VR, G, LR) { \
    float g_ = (G); \
    if (isnan(g_) || isinf(g_)) { g_ = 0.0; } \
    float m_ = pc.beta1 * (MR) + (1.0 - pc.beta1) * g_; \
    float v_ = pc.beta2 * (VR) + (1.0 - pc.beta2) * g_ * g_; \
    M = m_; \
    V = v_; \
    float d_ = sqrt(v_) / sqrt(pc.bc2) + pc.eps; \
    P = (PR) - ((LR) / pc.bc1) * m_ / d_; }

#ifdef COLOUR_ONLY
void put_mean(uint i, float g) {}
void put_scale(uint i, float g) {}
void put_quat(uint i, vec4 g) {}
void put_opacity(uint i, float g) {}
#else
void put_mean(uint i, float g) { ADAM_STEP(means[i], m1_means[i], m2_means[i], R_MEANS(i), R_M1_MEANS(i), R_M2_MEANS(i), g, pc.lr_means) }
void put_scale(uint i, float g) { ADAM_STEP(log_scales[i], m1_scales[i], m2_scales[i], R_LOG_SCALES(i), R_M1_SCALES(i), R_M2_SCALES(i), g, pc.lr_scales) }
void put_quat(uint i, vec4 g) {
    vec4 q = R_QUAT(i);
    for (uint k = 0u; k < 4u; k++) {
        ADAM_STEP(quats[i][k], m1_quats[4u * i + k], m2_quats[4u * i + k], q[k], R_M1_QUATS(4u * i + k), R_M2_QUATS(4u * i + k), g[k], pc.lr_quats)
    }
}
void put_opacity(uint i, float g) { ADAM_STEP(opacity[i], m1_opacity[i], m2_opacity[i], R_OPACITY(i), R_M1_OPACITY(i), R_M2_OPACITY(i), g, pc.lr_opacity) }
#endif
// Feature i of the Gaussian whose features start at fb, its value p
// already loaded.
void put_feat_from(uint fb, uint i, float p, float g) {
    if (i < pc.feat_active) {
        ADAM_STEP(W_FEATS(fb + i), W_M1_FEATS(fb + i), W_M2_FEATS(fb + i), p, R_M1_FEATS(fb + i), R_M2_FEATS(fb + i), g, i < pc.feat_split ? pc.lr_feats : pc.lr_rest)
    }
}
// The same, loading the value (only for a feature that steps).
void put_feat(uint fb, uint i, float g) {
    if (i < pc.feat_active) {
        put_feat_from(fb, i, R_FEATS(fb + i), g);
    }
}
#else
layout(std430, binding = 9) writeonly buffer GMeans { float g_means[]; };
layout(std430, binding = 10) writeonly buffer GScales { float g_scales[]; };
layout(std430, binding = 11) writeonly buffer GQuats { vec4 g_quats[]; };
layout(std430, binding = 12) writeonly buffer GOpac { float g_opacity[]; };
layout(std430, binding = 13) writeonly buffer GFeats { float g_feats[]; };

void put_mean(uint i, float g) { g_means[i] = g; }
void put_scale(uint i, float g) { g_scales[i] = g; }
void put_quat(uint i, vec4 g) { g_quats[i] = g; }
void put_opacity(uint i, float g) { g_opacity[i] = g; }
void put_feat(uint fb, uint i, float g) { g_feats[fb + i] = g; }
void put_feat_from(uint fb, uint i, float p, float g) { put_feat(fb, i, g); }
#endif

vec4 quat_rot_vjp(vec4 q, mat3 dR) {
    float r = q.x, x = q.y, y = q.z, z = q.w;
    // dIJ = dL/dR[row I][column J]; GLSL indexes dR[column][row].
    float d00 = dR[0][0], d10 = dR[0][1], d20 = dR[0][2];
    float d01 = dR[1][0], d11 = dR[1][1], d21 = dR[1][2];
    float d02 = dR[2][0], d12 = dR[2][1], d22 = dR[2][2];
    return 2.0 * vec4(
        -z * d01 + y * d02 + z * d10 - x * d12 - y * d20 + x * d21,
        y * d01 + z * d02 + y * d10 - 2.0 * x * d11 - r * d12 + z * d20 + r * d21 - 2.0 * x * d22,
        -2.0 * y * d00 + x * d01 + r * d02 + x * d10 + z * d12 - r * d20 + z * d21 - 2.0 * y * d22,
        -2.0 * z * d00 - r * d01 + x * d02 + r * d10 - 2.0 * z * d11 + y * d12 + x * d20 + y * d21);
}

void main() {
    uint r = wg_linear() * WG + gl_LocalInvocationID.x;
    if (r >= pc.n) {
        return;
    }
    uint g = IDS(r);
    // Another slice's Gaussian (feature slices: every slice's dispatch
    // walks every rank and takes its own).
    if (g < pc.feat_base || g >= pc.feat_end) {
        return;
    }
    uint p0 = min(OFFSETS(r), pc.capacity), p1 = min(OFFSETS(r + 1u), pc.capacity);

    vec3 dTu = vec3(0.0), dTv = vec3(0.0), dTw = vec3(0.0), dn = vec3(0.0);
    vec2 dmu = vec2(0.0);
    float dO = 0.0;
    float df[CH];
    for (uint c = 0u; c < CH; c++) {
        df[c] = 0.0;
    }
    for (uint p = p0; p < p1; p++) {
        uint b = p * KREC;
#ifndef COLOUR_ONLY
        dTu += vec3(REC(b), REC(b + 1u), REC(b + 2u));
        dTv += vec3(REC(b + 3u), REC(b + 4u), REC(b + 5u));
        dTw += vec3(REC(b + 6u), REC(b + 7u), REC(b + 8u));
        dmu += vec2(REC(b + 9u), REC(b + 10u));
        dO += REC(b + 11u);
        dn += vec3(REC(b + 12u), REC(b + 13u), REC(b + 14u));
#endif
        for (uint c = 0u; c < CH; c++) {
            df[c] += REC(b + 15u + c);
        }
    }

    vec3 p = vec3(R_MEANS(3u * g), R_MEANS(3u * g + 1u), R_MEANS(3u * g + 2u));
    vec2 ls = vec2(R_LOG_SCALES(2u * g), R_LOG_SCALES(2u * g + 1u));
    vec4 qr = R_QUAT(g);
    Proj pr;
    bool ok = p1 > p0 && project(p, ls, qr, R_OPACITY(g), pr);
    uint fb = (g - pc.feat_base) * pc.coeffs * CH;
    if (!ok) {
        put_mean(3u * g, 0.0); put_mean(3u * g + 1u, 0.0); put_mean(3u * g + 2u, 0.0);
        put_scale(2u * g, 0.0); put_scale(2u * g + 1u, 0.0);
        put_quat(g, vec4(0.0));
        put_opacity(g, 0.0);
        densify[g] = vec2(0.0);
        for (uint i = 0u; i < pc.coeffs * CH; i++) {
            put_feat(fb, i, 0.0);
        }
        return;
    }
    Splat s = pr.s;
    densify[g] = vec2(dTu.z * s.tw.z * 0.5 * float(pc.width), dTv.z * s.tw.z * 0.5 * float(pc.height));

    // Bounding-box centre mu = (f . (Tu*Tw), f . (Tv*Tw)), f = t / d, d = t . (Tw*Tw).
    const vec3 t = vec3(CUTOFF * CUTOFF, CUTOFF * CUTOFF, -1.0);
    dTu += dmu.x * pr.f * s.tw;
    dTv += dmu.y * pr.f * s.tw;
    dTw += dmu.x * (pr.f * s.tu - s.mu.x * 2.0 * t * s.tw / pr.d) + dmu.y * (pr.f * s.tv - s.mu.y * 2.0 * t * s.tw / pr.d);

    // T = K A with A = [s_u R t_u | s_v R t_v | p_view] (R: world -> view).
    vec4 k = intrinsics();
    vec3 dA0 = k.x * dTu, dA1 = k.y * dTv, dA2 = k.z * dTu + k.w * dTv + dTw;
    vec3 d_su_tu = view_rot_t(vec3(dA0.x, dA1.x, dA2.x));
    vec3 d_sv_tv = view_rot_t(vec3(dA0.y, dA1.y, dA2.y));
    vec3 dmean = view_rot_t(vec3(dA0.z, dA1.z, dA2.z));
    vec3 d_tw = pr.sgn * view_rot_t(dn);

    put_scale(2u * g, dot(pr.rot[0], d_su_tu) * pr.scale.x);
    put_scale(2u * g + 1u, dot(pr.rot[1], d_sv_tv) * pr.scale.y);
    float qlen = length(qr);
    vec4 qn = qr / qlen;
    vec4 dqn = quat_rot_vjp(qn, mat3(pr.scale.x * d_su_tu, pr.scale.y * d_sv_tv, d_tw));
    put_quat(g, (dqn - qn * dot(qn, dqn)) / qlen);
    // sigmoid'(x) = sigmoid(x) sigmoid(-x): 1 - o would cancel in f32 for
    // saturated opacities (1% error at x = 12).
    put_opacity(g, dO * s.o / (1.0 + exp(R_OPACITY(g))));

    if (pc.mode == 1u) {
        for (uint i = 0u; i < pc.coeffs * CH; i++) {
            put_feat(fb, i, i < CH ? df[i] : 0.0);
        }
    } else {
        float Y[16];
        vec3 dY[16];
        vec3 dirv = p - cam_centre();
        float len = length(dirv);
        vec3 dir = len > 0.0 ? dirv / len : vec3(0.0, 0.0, 1.0);
        sh_basis(dir, Y);
        sh_basis_grad(dir, dY);
        uint nk = active_coeffs();
        // The coefficients, loaded once (a storage-buffer load costs a
        // scalar load per lane on CPU drivers; they were read three times).
        // At most 16 (SH degree 3: Rasterizer::new refuses more, and Y
        // above holds 16).
        uint nc = min(pc.coeffs, 16u);
        float F[16u * CH];
        for (uint i = 0u; i < nc * CH; i++) {
            F[i] = R_FEATS(fb + i);
        }
        // precise: no fused multiply-adds into the direction gradient, so
        // the ADAM variant (whose loop also steps the coefficients) rounds
        // it as the plain reduce does.
        precise vec3 ddir = vec3(0.0);
#ifdef FEAT4
        // Each feature's gradient, stepped below four at a time: a store
        // costs a loop over the lanes on CPU drivers, whatever its width.
        float G[16u * CH];
#endif
        for (uint c = 0u; c < CH; c++) {
            float v = 0.5;
            for (uint kk = 0u; kk < nk; kk++) {
                v += Y[kk] * F[kk * CH + c];
            }
            float gc = v > 0.0 ? df[c] : 0.0;
            for (uint kk = 0u; kk < nc; kk++) {
                float coef = F[kk * CH + c];
                if (kk < nk) {
                    ddir += gc * coef * dY[kk];
                }
#ifdef FEAT4
                G[kk * CH + c] = kk < nk ? Y[kk] * gc : 0.0;
#else
                put_feat_from(fb, kk * CH + c, coef, kk < nk ? Y[kk] * gc : 0.0);
#endif
            }
        }
#ifdef FEAT4
        uint nf = nc * CH;
        if ((nf & 3u) == 0u && (fb & 3u) == 0u) {
            for (uint j = 0u; j < nf; j += 4u) {
                vec4 pv = vec4(F[j], F[j + 1u], F[j + 2u], F[j + 3u]);
                vec4 mv = vec4(R_M1_FEATS(fb + j), R_M1_FEATS(fb + j + 1u), R_M1_FEATS(fb + j + 2u), R_M1_FEATS(fb + j + 3u));
                vec4 vv = vec4(R_M2_FEATS(fb + j), R_M2_FEATS(fb + j + 1u), R_M2_FEATS(fb + j + 2u), R_M2_FEATS(fb + j + 3u));
                vec4 np = pv, nm = mv, nv = vv;
                for (uint t = 0u; t < 4u; t++) {
                    uint i = j + t;
                    if (i < pc.feat_active) {
                        ADAM_STEP(np[t], nm[t], nv[t], pv[t], mv[t], vv[t], G[i], i < pc.feat_split ? pc.lr_feats : pc.lr_rest)
                    }
                }
                feats4[(fb + j) >> 2u] = np;
                m1_feats4[(fb + j) >> 2u] = nm;
                m2_feats4[(fb + j) >> 2u] = nv;
            }
        } else {
            for (uint i = 0u; i < nf; i++) {
                put_feat_from(fb, i, F[i], G[i]);
            }
        }
#endif
        if (len > 0.0) {
            dmean += (ddir - dir * dot(dir, ddir)) / len;
        }
    }
    put_mean(3u * g, dmean.x);
    put_mean(3u * g + 1u, dmean.y);
    put_mean(3u * g + 2u, dmean.z);
}
