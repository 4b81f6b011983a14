// `groups` workgroups laid out as the host's `groups_2d` (engine/src/recorder.rs)
// lays them out: along x, at most max_x, then rows of them along y. For
// kernels that write indirect dispatch arguments from a GPU-held count.
#ifndef TGS_UTIL_GROUPS_2D_GLSL
#define TGS_UTIL_GROUPS_2D_GLSL
uvec3 groups_2d(uint groups, uint max_x) {
    bool one_row = groups <= max_x;
    return uvec3(one_row ? groups : max_x, one_row ? 1u : (groups + max_x - 1u) / max_x, 1u);
}
#endif
