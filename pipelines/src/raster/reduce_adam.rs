//! The backward with the Adam step fused into the per-Gaussian reduce
//! (`glsl/raster/reduce.comp`, variant `ADAM`): each Gaussian's gradient is
//! summed from its intersection records as in [`Rasterizer::record_backward`]
//! and then steps its parameters and moments directly, instead of being
//! written out for a separate Adam pass over every parameter array. The
//! arithmetic is adam/step.comp's, so the result equals the backward followed by
//! `Adam::record_set` (tests/tests/train_kernels.rs compares them bit for bit).

use super::{Frame, Gaussians, Push, Rasterizer};
use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use tgs_engine::{BufferBinding, Kernel, KernelDesc, Recorder};

/// The Adam step [`Rasterizer::record_backward_adam`] fuses into the
/// reduce: the set's first and second moments (each in the set's layout)
/// and the step's rates and constants.
#[derive(Clone, Copy)]
pub struct Moments<'a> {
    pub m: &'a Gaussians,
    pub v: &'a Gaussians,
    pub adam: &'a ReduceAdam,
    /// Step the features alone (a set whose geometry does not train): the
    /// feature-only tile backward and reduce; the geometry and its moments
    /// are left as they are, `frame.densify` is zero. The result is that of
    /// [`Rasterizer::record_backward_colour`] followed by Adam's pass over
    /// the features, bit for bit.
    pub features_only: bool,
}

/// Adam's rates and constants for [`Rasterizer::record_backward_adam`]
/// (the push-constant tail of the `ADAM` variant, in its order).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct ReduceAdam {
    pub lr_means: f32,
    pub lr_scales: f32,
    pub lr_quats: f32,
    pub lr_opacity: f32,
    /// Rate of each Gaussian's first `feat_split` features (the SH DC terms).
    pub lr_feats: f32,
    /// Rate of its other features.
    pub lr_rest: f32,
    pub feat_split: u32,
    /// Features stepped per Gaussian (those of the active SH degrees).
    pub feat_active: u32,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// 1 - beta1^t for step t.
    pub bc1: f32,
    /// 1 - beta2^t.
    pub bc2: f32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct PushAdam {
    base: Push,
    adam: ReduceAdam,
}

/// Storage buffers the fused reduce binds.
const BINDINGS: u32 = 20;
/// The bindings of the storage buffers that the `TEXEL` variant also reads
/// through texel views (bindings 20-34, in this order): the parameters and
/// both moments.
const TEXEL_VIEWS: [usize; 15] = [1, 2, 3, 4, 5, 9, 10, 11, 12, 13, 15, 16, 17, 18, 19];

impl Rasterizer {
    /// Whether this device can run [`Rasterizer::record_backward_adam`]
    /// (20 storage buffers in one shader and a 108-byte push constant).
    pub fn can_fuse_adam(&self) -> bool {
        let caps = self.ctx.caps();
        caps.max_storage_buffers_per_stage >= BINDINGS && caps.max_push_constants as usize >= std::mem::size_of::<PushAdam>()
    }

    /// The workgroups of [`Rasterizer::record_backward_adam`]'s reduce for
    /// `n` Gaussians (to gate it with [`Rasterizer::record_fit_gate`]).
    pub fn reduce_grid(&self, n: u32) -> [u32; 3] {
        self.groups(n)
    }

    /// Record the backward of the last forward on `frame` and an Adam step
    /// of `g` with `step`'s moments and rates, fused into the
    /// per-Gaussian reduce; `frame.densify` is written as by
    /// [`Rasterizer::record_backward`], no gradient buffer is. With `gate`
    /// (a slot from [`Rasterizer::record_fit_gate`] holding
    /// [`Rasterizer::reduce_grid`]) the reduce, and so the step, runs only
    /// when the view fitted its frame.
    pub fn record_backward_adam(&self, rec: &mut Recorder, g: &Gaussians, step: Moments, sh_degree: u32, frame: &Frame, gate: Option<&BufferBinding>) -> Result<()> {
        self.check_moments(g, &step)?;
        let records = self.record_tile_backward(rec, g, &g.features, sh_degree, frame, step.features_only)?;
        self.record_reduce_adam(rec, g, step, sh_degree, frame, records, gate)
    }

    /// Whether `step` fits the set `g` and this device runs the fused step.
    pub(super) fn check_moments(&self, g: &Gaussians, step: &Moments) -> Result<()> {
        let Moments { m, v, adam, .. } = *step;
        for (name, s) in [("first", m), ("second", v)] {
            if s.n != g.n || s.channels != g.channels || s.coeffs != g.coeffs {
                bail!("Adam's {name} moments ({} Gaussians, {} x {} features) do not match the Gaussian set ({}, {} x {})", s.n, s.channels, s.coeffs, g.n, g.channels, g.coeffs);
            }
        }
        let per = g.channels * g.coeffs;
        if adam.feat_active > per || adam.feat_split > per {
            bail!("Adam steps {} features per Gaussian (rate split at {}); the set has {per}", adam.feat_active, adam.feat_split);
        }
        if !self.can_fuse_adam() {
            bail!(
                "{} cannot run the fused reduce and Adam step ({BINDINGS} storage buffers, {} push-constant bytes)",
                self.ctx.caps().device_name,
                std::mem::size_of::<PushAdam>()
            );
        }
        Ok(())
    }

    /// The per-Gaussian reduce of the gradient records `records` (ranked by
    /// `frame.depth_ids`, ranges in `frame.offsets`) with `step`'s Adam
    /// step fused (see [`Rasterizer::record_backward_adam`]).
    #[allow(clippy::too_many_arguments)] // the kernel's bindings, each its own input
    pub(super) fn record_reduce_adam(
        &self,
        rec: &mut Recorder,
        g: &Gaussians,
        step: Moments,
        sh_degree: u32,
        frame: &Frame,
        records: BufferBinding,
        gate: Option<&BufferBinding>,
    ) -> Result<()> {
        let Moments { m, v, adam, features_only } = step;
        // CPU devices read the reduce's inputs as texel buffers where the
        // records fit one texel view (variant TEXEL): the same arithmetic.
        let texel = self.kernels == super::RasterKernels::Subgroup && frame.isect_grads.len() as u64 <= self.ctx.caps().max_texel_buffer_elements;
        let kernel = self.reduce_adam_kernel(features_only, texel)?;
        let sc = rec.begin_scope("raster.reduce");
        for slice in self.feature_slices(g.n) {
            let mut bindings = self.param_bindings(frame, g, &g.features, slice);
            bindings.extend([frame.depth_ids.binding(), frame.offsets.binding(), records.clone()]);
            bindings.extend(m.buffers().map(|b| b.binding()));
            bindings[13] = self.feature_binding(&m.features, slice);
            bindings.push(frame.densify.binding());
            bindings.extend(v.buffers().map(|b| b.binding()));
            bindings[19] = self.feature_binding(&v.features, slice);
            if texel {
                // The records themselves (not their address), and the views.
                bindings[8] = frame.isect_grads.binding();
                let views: Vec<_> = TEXEL_VIEWS.iter().map(|&i| bindings[i].clone()).collect();
                bindings.extend(views);
            }
            let push = PushAdam { base: Push { feat_base: slice.0, feat_end: slice.1, ..self.push(g, frame, sh_degree) }, adam: *adam };
            match gate {
                Some(args) => rec.dispatch_indirect(kernel, &bindings, bytemuck::bytes_of(&push), args)?,
                None => rec.dispatch(kernel, &bindings, bytemuck::bytes_of(&push), self.groups(g.n))?,
            }
        }
        rec.end_scope(sc);
        Ok(())
    }

    fn reduce_adam_kernel(&self, features_only: bool, texel: bool) -> Result<&Kernel> {
        let slot = &self.reduce_adam[features_only as usize + 2 * texel as usize];
        if let Some(k) = slot.get() {
            return Ok(k);
        }
        let spirv = match (self.records, features_only, texel) {
            (_, false, true) => shaders::RASTER_REDUCE_ADAM_TEXEL,
            (_, true, true) => shaders::RASTER_REDUCE_ADAM_COLOUR_ONLY_TEXEL,
            (super::RecordAccess::Address, false, false) => shaders::RASTER_REDUCE_ADAM_RECORDS_BDA,
            (super::RecordAccess::Binding, false, false) => shaders::RASTER_REDUCE_ADAM,
            (super::RecordAccess::Address, true, false) => shaders::RASTER_REDUCE_ADAM_COLOUR_ONLY_RECORDS_BDA,
            (super::RecordAccess::Binding, true, false) => shaders::RASTER_REDUCE_ADAM_COLOUR_ONLY,
        };
        let min_sg = self.ctx.caps().min_subgroup_size.max(1);
        let spec = [(0, super::WG), (1, min_sg), (4, self.channels), (5, self.batch)];
        let push_bytes = std::mem::size_of::<PushAdam>() as u32;
        let k = Kernel::new(&self.ctx, &KernelDesc { name: "raster.reduce_adam", spirv, spec: &spec, push_bytes, subgroup_size: None, full_subgroups: false })?;
        Ok(slot.get_or_init(|| k))
    }
}
