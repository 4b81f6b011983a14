// The MLP GEMMs' shared pieces (mlp/gemm.comp, mlp/gemm_rows.comp).
//
// The weight gradients' split of the samples into chunks, each summed by
// its own workgroups into its own partial (pipelines/src/mlp weight_chunks,
// which must agree: tests/tests/mlp.rs compares the counted and host paths
// bit for bit): at most MAX_CHUNKS chunks of a multiple of 16 samples, at
// least MIN_CHUNK.
const uint MAX_CHUNKS = 16u;
const uint MIN_CHUNK = 256u;

uint weight_chunk(uint n) {
    uint c = (n + MAX_CHUNKS - 1u) / MAX_CHUNKS;
    return max((c + 15u) / 16u * 16u, MIN_CHUNK);
}

uint weight_chunk_count(uint n) {
    return max((n + weight_chunk(n) - 1u) / weight_chunk(n), 1u);
}

// The walk of a counted grid (a power of two of workgroups along z): g's
// bits reversed within log2(n) bits, so that the busy workgroups (the first
// chunks) spread over the grid.
uint spread(uint g, uint n) {
    return n <= 1u ? g : bitfieldReverse(g) >> (32u - uint(findMSB(n)));
}
