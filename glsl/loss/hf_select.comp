#version 460
// High-frequency loss, selection (paper §3.5, method-notes §3.6): per pixel
// e = mean_c |I - I_gt|; tau = the value of rank floor(p (n - 1)) of the
// ascending e (exact: a radix select on the bit patterns of the
// non-negative floats, digits of 11, 11 and 10 bits, MSB first); then the
// count and the sum of the e >= tau (ties included). One workgroup.
// Output: stats = [3 tau, count, sum, sum / count] (count as a float).
//
// The digit histograms count with shared integer atomics (exact, so the
// result does not depend on the order); the sum is each invocation's
// strided pixels in order, then a fixed tree over invocations.
#include "common.glsl"

layout(std430, binding = 0) readonly buffer Render { float render[]; };
layout(std430, binding = 1) readonly buffer Target { float target[]; };
layout(std430, binding = 2) writeonly buffer Stats { float stats[]; };
layout(push_constant) uniform Push {
    uint n;         // pixels (planes of n floats; the first 3 are colour)
    float pct;      // p in [0, 1]
} pc;

const uint BINS = 2048u;
shared uint hist[BINS];
shared uint sel[2];  // prefix so far, remaining rank
shared float psum[256];
shared uint pcnt[256];

// 3 e (the division is left to the end: the sum of three absolute values
// rounds the same on every device, so ties stay ties).
float err(uint i) {
    uint n = pc.n;
    float e = abs(render[i] - target[i]) + abs(render[n + i] - target[n + i]) + abs(render[2u * n + i] - target[2u * n + i]);
    // NaN counts as 0 (it cannot win the percentile or the sum); +inf stays.
    return isnan(e) ? 0.0 : e;
}

void main() {
    uint lid = gl_LocalInvocationID.x;
    uint n = pc.n;
    if (lid == 0u) {
        sel[0] = 0u;
        sel[1] = uint(floor(clamp(pc.pct, 0.0, 1.0) * float(n - 1u)));
    }
    // Digits: bits [21, 32), [10, 21), [0, 10).
    for (uint d = 0u; d < 3u; d++) {
        uint shift = d == 0u ? 21u : (d == 1u ? 10u : 0u);
        uint width = d == 2u ? 10u : 11u;
        uint hi = shift + width;  // bits above this digit are the prefix
        for (uint b = lid; b < BINS; b += WG) {
            hist[b] = 0u;
        }
        barrier();
        uint prefix = sel[0];
        for (uint i = lid; i < n; i += WG) {
            uint k = floatBitsToUint(err(i));
            bool match = hi >= 32u || (k >> hi) == (prefix >> hi);
            if (match) {
                atomicAdd(hist[(k >> shift) & ((1u << width) - 1u)], 1u);
            }
        }
        barrier();
        if (lid == 0u) {
            uint rank = sel[1], b = 0u;
            for (; b + 1u < (1u << width); b++) {
                if (rank < hist[b]) {
                    break;
                }
                rank -= hist[b];
            }
            sel[0] = prefix | (b << shift);
            sel[1] = rank;
        }
        barrier();
    }
    uint tau = sel[0];
    float s = 0.0;
    uint c = 0u;
    for (uint i = lid; i < n; i += WG) {
        float e = err(i);
        if (floatBitsToUint(e) >= tau) {
            s += e;
            c += 1u;
        }
    }
    psum[lid] = s;
    pcnt[lid] = c;
    barrier();
    for (uint h = WG / 2u; h > 0u; h /= 2u) {
        if (lid < h) {
            psum[lid] += psum[lid + h];
            pcnt[lid] += pcnt[lid + h];
        }
        barrier();
    }
    if (lid == 0u) {
        stats[0] = uintBitsToFloat(tau);
        stats[1] = float(pcnt[0]);
        stats[2] = psum[0] / 3.0;
        stats[3] = psum[0] / (3.0 * float(max(pcnt[0], 1u)));
    }
}
