//! The fused light-field kernels ([`Gemm::Fused`](super::Gemm::Fused);
//! `glsl/mlp/fused_forward.comp`, `glsl/mlp/fused_backward.comp`, the
//! scheme in `glsl/mlp/fused_common.glsl`): the forward from the encoding
//! to the head in one dispatch and the input gradients from the head's dZ
//! down in another, a workgroup's activations in shared memory
//! throughout. The weight gradients stay split-k GEMM products. Each
//! element is summed in the GEMMs' order, so outputs and gradients are the
//! same bits as the layer-by-layer kernels' (tests/tests/mlp.rs).
//!
//! The kernels depend on the network's shape (their register blocks and
//! shared arrays are specialisation constants), so a scratch of that shape
//! holds them.

use super::{Block, MlpShape, OUT, SAMPLE};
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{groups_2d, Buffer, BufferBinding, Context, Kernel, KernelDesc, Recorder};

use crate::shaders;

/// The widest layer the fused kernels take (8 x 32 columns per workgroup,
/// 64 accumulators per invocation at 2 rows).
pub const FUSED_MAX_WIDTH: u32 = 256;

/// Push constants of both fused kernels (`glsl/mlp/fused_common.glsl`).
#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    n: u32,
    base: u32,
    n_count: u32,
    width: u32,
    depth: u32,
    skip: u32,
    levels_x: u32,
    levels_w: u32,
    layer_stride: u32,
}

/// The register block and shared arrays of a shape's fused kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) struct FusedPlan {
    /// Rows per invocation (a workgroup takes 8 rb samples).
    pub(super) rb: u32,
    /// Columns per invocation (layers up to 8 cb wide).
    pub(super) cb: u32,
    /// Rows of B staged in shared memory at a time.
    pub(super) kc: u32,
}

impl FusedPlan {
    /// The largest block (4 rows per invocation for widths up to 64, else
    /// 2; then 1) and weight stage (8 rows, else 4) whose shared arrays fit
    /// `max_shared` bytes.
    pub(super) fn for_shape(shape: &MlpShape, max_shared: u32) -> Result<FusedPlan> {
        if shape.width > FUSED_MAX_WIDTH {
            bail!("the fused light-field kernels take layers up to {FUSED_MAX_WIDTH} wide; this network's are {} (choose the tiled or row kernel: TGS_MLP_GEMM)", shape.width);
        }
        let cb = shape.width.div_ceil(8).max(1);
        let mut rb = if shape.width <= 64 { 4 } else { 2 };
        loop {
            for kc in [8, 4] {
                let plan = FusedPlan { rb, cb, kc };
                if plan.shared_bytes(shape) <= max_shared as u64 {
                    return Ok(plan);
                }
            }
            if rb == 1 {
                bail!(
                    "the fused light-field kernels need {} bytes of shared memory for a network {} wide with Fourier levels ({}, {}); this device has {max_shared}",
                    FusedPlan { rb, cb, kc: 4 }.shared_bytes(shape),
                    shape.width,
                    shape.levels_x,
                    shape.levels_w
                );
            }
            rb /= 2;
        }
    }
    /// Samples per workgroup.
    pub(super) fn rows(&self) -> u32 {
        8 * self.rb
    }
    /// Shared bytes of the larger kernel: the forward's activations
    /// (cat_width per row) or the backward's dZ (8 cb per row), and the
    /// staged weights.
    fn shared_bytes(&self, shape: &MlpShape) -> u64 {
        let wmax = 8 * self.cb as u64;
        let rows = self.rows() as u64;
        let act = rows * shape.cat_width() as u64;
        4 * (act.max(rows * wmax) + self.kc as u64 * wmax)
    }
}

/// A shape's fused kernels and the activations they keep for the weight
/// gradients, for blocks of up to `block` samples.
pub(super) struct Fused {
    plan: FusedPlan,
    forward: Kernel,
    backward: Kernel,
    /// Hidden layer l's output at l layer_stride (row stride width), but
    /// the one the skip layer reads (in the scratch's `cat`).
    pub(super) stack: Buffer<f32>,
    /// Layer l's dZ at l layer_stride (row stride its width; the head's 3).
    pub(super) dz: Buffer<f32>,
    pub(super) layer_stride: u32,
}

/// The buffers a fused forward or backward binds besides the scratch's own.
pub(super) struct FusedIo<'a> {
    pub(super) samples: &'a Buffer<f32>,
    pub(super) params: &'a Buffer<f32>,
    pub(super) in0: &'a Buffer<f32>,
    pub(super) cat: &'a Buffer<f32>,
    pub(super) out: &'a Buffer<f32>,
}

impl Fused {
    /// Floats per sample of the widest buffer [`Fused`] holds (the dZ of
    /// every layer), for the scratch's check against one binding.
    pub(super) fn floats_per_sample(shape: &MlpShape) -> u64 {
        shape.width.max(OUT) as u64 * (shape.depth as u64 + 1)
    }

    pub(super) fn new(ctx: &Arc<Context>, shape: MlpShape, block: u32) -> Result<Fused> {
        let plan = FusedPlan::for_shape(&shape, ctx.caps().max_shared_memory)?;
        // The workgroup is the 8 x 8 grid of glsl/mlp/fused_common.glsl.
        let spec = [(0, 64), (3, plan.rb), (4, plan.cb), (5, shape.cat_width()), (6, plan.kc)];
        let push_bytes = std::mem::size_of::<Push>() as u32;
        let kernel = |name, spirv| Kernel::new(ctx, &KernelDesc { name, spirv, spec: &spec, push_bytes, subgroup_size: None, full_subgroups: false });
        let layer_stride = block.max(1) * shape.width.max(OUT);
        let ls = layer_stride as usize;
        Ok(Fused {
            plan,
            forward: kernel("mlp.fused_forward", shaders::MLP_FUSED_FORWARD)?,
            backward: kernel("mlp.fused_backward", shaders::MLP_FUSED_BACKWARD)?,
            stack: Buffer::uninit(ctx, "mlp.stack", ls * shape.depth as usize)?,
            dz: Buffer::uninit(ctx, "mlp.dz", ls * (shape.depth as usize + 1))?,
            layer_stride,
        })
    }

    pub(super) fn bytes(&self) -> u64 {
        self.stack.bytes() + self.dz.bytes()
    }

    fn push(&self, shape: &MlpShape, b: Block, counted: bool) -> Push {
        Push {
            n: b.m,
            base: b.base,
            n_count: counted as u32,
            width: shape.width,
            depth: shape.depth,
            skip: shape.skip,
            levels_x: shape.levels_x,
            levels_w: shape.levels_w,
            layer_stride: self.layer_stride,
        }
    }

    fn groups(&self, ctx: &Context, m: u32) -> [u32; 3] {
        groups_2d(m.div_ceil(self.plan.rows()).max(1), ctx.caps().max_workgroup_count[0].min(65535))
    }

    /// Phi of samples [b.base, b.base + b.m) (with `rows`, of the first
    /// min(b.m, rows[0])), and the activations the backward reads.
    pub(super) fn record_forward(&self, rec: &mut Recorder, shape: &MlpShape, io: FusedIo, b: Block, rows: Option<&Buffer<u32>>) -> Result<()> {
        debug_assert!(io.samples.len() >= ((b.base + b.m) * SAMPLE) as usize);
        let r = rows.map(|r| r.binding()).unwrap_or_else(|| io.samples.binding());
        let bindings: [BufferBinding; 7] = [io.samples.binding(), io.params.binding(), io.in0.binding(), io.cat.binding(), self.stack.binding(), io.out.binding(), r];
        let push = self.push(shape, b, rows.is_some());
        let groups = self.groups(rec.context(), b.m);
        rec.dispatch(&self.forward, &bindings, bytemuck::bytes_of(&push), groups)
    }

    /// Every layer's dZ of the block after its forward, from the output
    /// gradient `d_out` (RGB per sample, at the block's place).
    pub(super) fn record_backward(&self, rec: &mut Recorder, shape: &MlpShape, io: FusedIo, d_out: &Buffer<f32>, b: Block, rows: Option<&Buffer<u32>>) -> Result<()> {
        let r = rows.map(|r| r.binding()).unwrap_or_else(|| io.params.binding());
        let bindings: [BufferBinding; 7] = [io.params.binding(), io.out.binding(), d_out.binding(), io.cat.binding(), self.stack.binding(), self.dz.binding(), r];
        let push = self.push(shape, b, rows.is_some());
        let groups = self.groups(rec.context(), b.m);
        rec.dispatch(&self.backward, &bindings, bytemuck::bytes_of(&push), groups)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The plan takes the largest block that fits: the small network's 32
    /// samples everywhere; the paper network's 16 with 8 staged rows in
    /// NVIDIA's 48 KiB, with 4 in lavapipe's 32 KiB, 8 samples in 20 KiB;
    /// nothing in 4 KiB, and nothing wider than 256 (named).
    #[test]
    fn plans_fit_the_shared_memory() {
        let plan = |shape: &MlpShape, kib: u32| FusedPlan::for_shape(shape, kib * 1024).map(|p| (p.rows(), p.cb, p.kc));
        assert_eq!(plan(&MlpShape::SMALL, 32).unwrap(), (32, 8, 8));
        assert_eq!(plan(&MlpShape::PAPER, 48).unwrap(), (16, 32, 8));
        assert_eq!(plan(&MlpShape::PAPER, 32).unwrap(), (16, 32, 4));
        assert_eq!(plan(&MlpShape::PAPER, 20).unwrap(), (8, 32, 4));
        for (kib, shape) in [(4, MlpShape::PAPER), (32, MlpShape { width: FUSED_MAX_WIDTH + 1, ..MlpShape::PAPER })] {
            let e = plan(&shape, kib).unwrap_err().to_string();
            assert!(e.contains("fused light-field kernels"), "{e}");
        }
        for kib in [20, 32, 48] {
            for shape in [MlpShape::SMALL, MlpShape::PAPER] {
                let p = FusedPlan::for_shape(&shape, kib * 1024).unwrap();
                assert!(p.shared_bytes(&shape) <= kib as u64 * 1024 && 8 * p.cb >= shape.width);
            }
        }
    }
}
