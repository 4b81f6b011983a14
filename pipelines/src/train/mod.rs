//! Training kernels: the image loss (L1 + D-SSIM, normal consistency,
//! distortion weight) forward and backward, the high-frequency loss, the
//! fused Adam step, and the
//! adaptive density control (statistics, clone/split/prune with scan
//! compaction, opacity reset) on a trainable Gaussian set, and the
//! divergence guard.

mod adam;
mod densify;
mod guard;
mod hf;
mod loss;
mod set;

pub use adam::{Adam, AdamArrays, AdamGroup};
pub use densify::{Densifier, DensifyParams, DensifyReport};
pub use guard::{Guard, SetGuard};
pub use hf::{HfLoss, HfStats};
pub use loss::{ImageLoss, LossIo, LossScratch, LossValues, LossWeights};
pub use set::TrainableSet;

use tgs_engine::{groups_2d, BufferBinding, Context, Kernel, Recorder};

use crate::WG;

/// Grid of one invocation per item (2-D beyond the per-dimension limit).
pub(crate) fn grid(ctx: &Context, items: u32) -> [u32; 3] {
    groups_2d(items.div_ceil(WG), ctx.caps().max_workgroup_count[0].min(65535))
}

/// Dispatch `kernel` over `items` invocations ([`grid`]), or with the
/// workgroup counts read from `args` when the dispatch is gated
/// (`Rasterizer::record_fit_gate`; zero groups skip it).
pub(crate) fn dispatch_items(rec: &mut Recorder, kernel: &Kernel, bindings: &[BufferBinding], push: &[u8], items: u32, args: Option<&BufferBinding>) -> anyhow::Result<()> {
    match args {
        Some(a) => rec.dispatch_indirect(kernel, bindings, push, a),
        None => rec.dispatch(kernel, bindings, push, grid(rec.context(), items)),
    }
}

/// Linear workgroup count of [`grid`] (partial-sum slots).
pub(crate) fn grid_len(ctx: &Context, items: u32) -> u32 {
    let g = grid(ctx, items);
    g[0] * g[1] * g[2]
}

pub(crate) fn kernel(ctx: &std::sync::Arc<Context>, name: &str, spirv: &[u8], push_bytes: u32) -> anyhow::Result<tgs_engine::Kernel> {
    let spec = [(0, WG), (1, ctx.caps().min_subgroup_size.max(1)), (2, 1)];
    tgs_engine::Kernel::new(ctx, &tgs_engine::KernelDesc { name, spirv, spec: &spec, push_bytes, subgroup_size: None, full_subgroups: false })
}
