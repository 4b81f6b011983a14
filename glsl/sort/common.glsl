// Shared pieces of the LSD radix sort.
#ifndef TGS_SORT_COMMON_GLSL
#define TGS_SORT_COMMON_GLSL
#include "common.glsl"

layout(constant_id = 3) const uint RADIX_BITS = 4;
#define RADIX (1u << RADIX_BITS)

layout(push_constant) uniform Push {
    uint shift;      // first bit of this pass's digit
    uint bits;       // bits in this pass's digit (<= RADIX_BITS)
} pc;

uint digit_of(uint key) {
    return (key >> pc.shift) & ((1u << pc.bits) - 1u);
}

#endif
