//! The GEMM the light field's products run on: which kernel (tiled
//! through shared memory on GPUs, rows per invocation on CPU devices), the
//! block each product is cut into, and the product's description as the
//! kernels read it (push constants).

use anyhow::{bail, Context as _, Result};
use bytemuck::{Pod, Zeroable};
use tgs_engine::{Capabilities, Context};

/// Rows and columns of C per invocation of the tiled GEMM (its tile is 8x
/// that; glsl/mlp/gemm.comp): the largest whose tile fits the product's
/// smaller side, up to 16 (measured on llvmpipe, 8 x 256 on 4,096 samples:
/// blocks of 4 / 8 / 16 give 2.0 / 3.9 / 7.1 GFLOP/s forward).
pub(super) const BLOCKS: [u32; 3] = [4, 8, 16];
/// A configuration of the row kernel (glsl/mlp/gemm_rows.comp): `nb`
/// columns and `rr` rows of C per invocation, `wg` invocations per
/// workgroup (which covers wg x rr rows).
#[derive(Clone, Copy, Debug)]
pub(super) struct RowConfig {
    pub(super) nb: u32,
    pub(super) rr: u32,
    pub(super) wg: u32,
}

/// Column blocks the row kernel has pipelines for.
const COLUMN_BLOCKS: [u32; 4] = [8, 16, 32, 64];

/// The row kernel's workgroup shapes, (rows per invocation, invocations),
/// each with a pipeline per column block: 32 invocations with 8 rows each
/// for products with many rows (the forward and the input gradient: a row
/// per sample; the paper network's weight gradients, a row per output unit,
/// 256), 8 with 8 rows for products of at most 64 rows (the small
/// network's weight gradients), and 8 with 1 row for at most 8 (the head's
/// weight gradient). Rows per invocation share every broadcast of B and
/// columns share every load of A: measured on llvmpipe, the small network's
/// forward on 4,096 samples takes 131 / 80 / 55 / 44 ms with 1 / 2 / 4 / 8
/// rows (twenty-eighth session), and 8 rows with 64 columns (512
/// accumulators per invocation, which spill either way) beat 32 columns
/// and 4 rows with 64 (fortieth session, perf/RESULTS.md).
const ROW_GROUPS: [(u32, u32); 3] = [(8, 32), (8, 8), (1, 8)];

/// The row kernel's pipelines: configuration `g * 4 + c` is row group `g`
/// ([`ROW_GROUPS`]) with column block `c` ([`COLUMN_BLOCKS`]).
pub(super) const ROW_CONFIGS: [RowConfig; 12] = {
    let mut out = [RowConfig { nb: 0, rr: 0, wg: 0 }; 12];
    let mut i = 0;
    while i < out.len() {
        let (rr, wg) = ROW_GROUPS[i / COLUMN_BLOCKS.len()];
        out[i] = RowConfig { nb: COLUMN_BLOCKS[i % COLUMN_BLOCKS.len()], rr, wg };
        i += 1;
    }
    out
};

/// The first configuration of the smallest row group that covers `m` rows.
fn row_group(m: u32) -> usize {
    let g = if m <= 8 {
        2
    } else if m <= 64 {
        1
    } else {
        0
    };
    g * COLUMN_BLOCKS.len()
}

/// The column blocks a row-kernel product of `m` x `n` is dispatched in:
/// (first column, columns, configuration). As many whole blocks of
/// [`row_config`]'s width as fit, then the columns left over (the weight
/// gradients' bias column makes 65, 143 and 257 of 64, 128 and 256) in
/// narrower blocks instead of a wide block of zeros: the smallest block
/// that holds them if it wastes fewer than 8 columns, else the widest that
/// they fill. Each element of C is still summed by one invocation in
/// increasing k, so the results do not change.
pub(super) fn row_column_blocks(m: u32, n: u32) -> Vec<(u32, u32, usize)> {
    let first = row_config(m, n);
    let nb = ROW_CONFIGS[first].nb;
    if n <= nb || n.is_multiple_of(nb) {
        return vec![(0, n, first)];
    }
    let main = n / nb * nb;
    let mut out = vec![(0, main, first)];
    let mut j0 = main;
    let narrow = &COLUMN_BLOCKS[..3];
    while j0 < n {
        let left = n - j0;
        let col = match narrow.iter().position(|&b| b >= left) {
            Some(c) if narrow[c] - left < 8 => c,
            _ => narrow.iter().rposition(|&b| b <= left).unwrap_or(0),
        };
        let take = if left >= narrow[col] { left / narrow[col] * narrow[col] } else { left };
        out.push((j0, take, row_group(m) + col));
        j0 += take;
    }
    out
}

/// The row configuration for a product of `m` x `n`: 64 columns for
/// products at least 64 wide, else the smallest block that holds them (8,
/// 16, 32); the smallest workgroup shape that covers the rows.
pub(super) fn row_config(m: u32, n: u32) -> usize {
    let col = if n >= 64 { 3 } else { COLUMN_BLOCKS.iter().position(|&nb| nb >= n).unwrap_or(2) };
    row_group(m) + col
}
/// At most this many sample chunks hold weight-gradient partials (a power
/// of two: the counted backward walks them in bit-reversed order).
pub(super) const MAX_CHUNKS: u32 = 16;
const _: () = assert!(MAX_CHUNKS.is_power_of_two());
/// Smallest chunk of samples per weight-gradient partial.
pub(super) const MIN_CHUNK: u32 = 256;
pub(super) const NONE: u32 = u32::MAX;

/// Push constants of glsl/mlp/gemm.comp: C = post(A B) with element (i, k)
/// of A at a_off + i a_rs + k a_cs (column a_ones_k implicitly 1), B(k, j)
/// likewise (column b_ones_j implicitly 1), C(i, j) at
/// c_off + z c_zstride + i c_rs + j; post by `c_act` (with
/// [`RELU_DERIV`], Y(i, j) at y_off + i y_rs + j y_cs).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable, Default)]
pub(super) struct Product {
    pub(super) m: u32,
    pub(super) n: u32,
    pub(super) kdim: u32,
    pub(super) k_chunk: u32,
    pub(super) a_off: u32,
    pub(super) a_rs: u32,
    pub(super) a_cs: u32,
    pub(super) a_ones_k: u32,
    pub(super) b_off: u32,
    pub(super) b_rs: u32,
    pub(super) b_cs: u32,
    pub(super) b_ones_j: u32,
    pub(super) y_off: u32,
    pub(super) y_rs: u32,
    pub(super) y_cs: u32,
    pub(super) c_off: u32,
    pub(super) c_rs: u32,
    pub(super) c_zstride: u32,
    pub(super) c_act: u32,
    /// Rows from the GPU: m = min(m, rows[0]) (binding 4).
    pub(super) m_count: u32,
    /// The summed dimension from the GPU: kdim = min(kdim, rows[0]), split
    /// as [`weight_chunks`] would (k_chunk unused).
    pub(super) k_count: u32,
}

pub(super) const RELU: u32 = 1;
pub(super) const SIGMOID: u32 = 2;
/// `c_act`: C(i, j) kept where Y(i, j) > 0, else 0 (an input gradient
/// written as the ReLU layer below's dZ; Y from the `y_*` fields).
pub(super) const RELU_DERIV: u32 = 3;

/// The kernel the MLP's products run on. Both sum every element of C in
/// increasing k with one invocation, so their results are bit-identical
/// (tests/tests/mlp.rs); they differ in where the operands come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gemm {
    /// glsl/mlp/gemm.comp: tiles of A and B staged in shared memory; for
    /// GPUs, where shared memory is fast and global loads coalesce.
    Tiled,
    /// glsl/mlp/gemm_rows.comp: rows of C per invocation, their A from
    /// memory, B shared across the subgroup by broadcasts; for CPU devices
    /// (lavapipe), where every load a lane makes costs a scalar load and the
    /// tiled kernel's shared-memory reads were the bottleneck. Measured on
    /// llvmpipe, 4,096 samples, forward + backward: the small network 5,131
    /// -> 25,915 samples/s, the paper network 434 -> 1,260. Its operands
    /// are bound as uniform texel buffers (llvmpipe gathers a texel fetch;
    /// it loops over the lanes for a storage-buffer load), so each binding
    /// is also held to the device's `maxTexelBufferElements`.
    Rows,
    /// The forward from the encoding to the head in one kernel and the
    /// input gradients from the head's dZ down in another
    /// (glsl/mlp/fused_*.comp, tiny-cuda-nn's fully fused MLP without
    /// tensor cores: a workgroup's activations stay in shared memory); the
    /// weight gradients on the tiled GEMM. For GPUs, layers up to
    /// [`FUSED_MAX_WIDTH`](super::FUSED_MAX_WIDTH) wide; opt-in
    /// (`TGS_MLP_GEMM=fused`) until a GPU has measured it.
    Fused,
}

/// The environment variable that overrides [`Gemm::for_device`].
pub const GEMM_ENV: &str = "TGS_MLP_GEMM";

impl Gemm {
    /// Rows on CPU devices, tiled elsewhere; the environment variable
    /// `TGS_MLP_GEMM` (tiled, rows, fused) overrides the choice.
    pub fn for_device(ctx: &Context) -> Result<Gemm> {
        if let Ok(v) = std::env::var(GEMM_ENV) {
            return Gemm::parse(&v).with_context(|| format!("environment variable {GEMM_ENV}"));
        }
        Ok(if ctx.caps().is_cpu() { Gemm::Rows } else { Gemm::Tiled })
    }
    /// By name: "tiled", "rows" or "fused".
    pub fn parse(name: &str) -> Result<Gemm> {
        match name {
            "tiled" => Ok(Gemm::Tiled),
            "rows" => Ok(Gemm::Rows),
            "fused" => Ok(Gemm::Fused),
            _ => bail!("unknown MLP kernel '{name}' (tiled, rows, fused)"),
        }
    }
    /// Floats one binding of this kernel may hold on a device: a storage
    /// buffer's range, and for the row kernel (which reads its operands as
    /// texel buffers) the texels of one texel-buffer view too.
    pub(super) fn max_binding_floats(&self, caps: &Capabilities) -> u64 {
        let storage = caps.max_storage_buffer_range / 4;
        match self {
            Gemm::Rows => storage.min(caps.max_texel_buffer_elements),
            Gemm::Tiled | Gemm::Fused => storage,
        }
    }
    pub fn name(&self) -> &'static str {
        match self {
            Gemm::Tiled => "tiled",
            Gemm::Fused => "fused",
            Gemm::Rows => "rows",
        }
    }
}
