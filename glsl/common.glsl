// Shared definitions for all tgs compute kernels.
//
// Specialization constant ids used across kernels:
//   0: workgroup size x (local_size_x_id = 0)
//   1: MIN_SG   smallest subgroup size the device may run (sizes shared arrays)
//   2: KPT      items per invocation
//   3: RADIX_BITS digit width of the radix sort
#ifndef TGS_COMMON_GLSL
#define TGS_COMMON_GLSL

#extension GL_KHR_shader_subgroup_basic : require
#extension GL_KHR_shader_subgroup_arithmetic : require
#extension GL_KHR_shader_subgroup_ballot : require
#extension GL_KHR_shader_subgroup_vote : require

layout(local_size_x_id = 0, local_size_y = 1, local_size_z = 1) in;
layout(constant_id = 1) const uint MIN_SG = 4;
layout(constant_id = 2) const uint KPT = 4;

#define WG (gl_WorkGroupSize.x)
// Upper bound on gl_NumSubgroups for this workgroup size.
#define MAX_SG (gl_WorkGroupSize.x / MIN_SG)

// Workgroups are dispatched as a 2-D grid when there are more than the
// per-dimension limit (65,535 on lavapipe); this is the linear id.
uint wg_linear() {
    return gl_WorkGroupID.x + gl_WorkGroupID.y * gl_NumWorkGroups.x;
}

#endif
