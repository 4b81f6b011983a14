//! The high-frequency loss (paper §3.5, method-notes §3.6): the mean
//! per-pixel error of the pixels at or above the p-th percentile of the
//! error, the percentile found on the GPU by an exact radix select.

use super::loss::LossIo;
use super::{grid, kernel};
use crate::shaders;
use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Kernel, KernelDesc, Readback, Recorder};

/// Selection workgroup size (glsl/loss/hf_select.comp's reduction tree).
const SELECT_WG: u32 = 256;

pub struct HfLoss {
    ctx: Arc<Context>,
    select: Kernel,
    grad: Kernel,
}

/// The selection's result: [3 tau, count, sum, mean], and its host copy
/// that rides back with the submission that recorded the loss.
pub struct HfStats {
    pub stats: Buffer<f32>,
    stats_host: Readback<f32>,
}

impl HfStats {
    /// (3 tau: the threshold on the sum of the three channels' absolute
    /// errors, count, mean error of the selected pixels) of the last
    /// submitted [`HfLoss::record`] (no transfer of its own).
    pub fn values(&self) -> Result<(f32, u32, f64)> {
        let s = self.stats_host.read()?;
        Ok((s[0], s[1] as u32, s[3] as f64))
    }
}

impl HfLoss {
    pub fn new(ctx: &Arc<Context>) -> Result<HfLoss> {
        let spec = [(0, SELECT_WG), (1, ctx.caps().min_subgroup_size.max(1)), (2, 1)];
        let select =
            Kernel::new(ctx, &KernelDesc { name: "loss.hf_select", spirv: shaders::LOSS_HF_SELECT, spec: &spec, push_bytes: 8, subgroup_size: None, full_subgroups: false })?;
        Ok(HfLoss { ctx: ctx.clone(), select, grad: kernel(ctx, "loss.hf_grad", shaders::LOSS_HF_GRAD, 8)? })
    }

    pub fn stats(&self) -> Result<HfStats> {
        Ok(HfStats { stats: Buffer::new(&self.ctx, "loss.hf_stats", 4)?, stats_host: Readback::new(&self.ctx, "loss.hf_stats_host", 4)? })
    }

    /// Record the loss of the colour planes of `io.render` (`pixels` per
    /// plane) against `io.target` at percentile `pct` (in [0, 1]) into `s`,
    /// and add `weight` x its gradient to the colour planes of `io.grad`.
    pub fn record(&self, rec: &mut Recorder, io: LossIo, pixels: u32, pct: f32, weight: f32, s: &HfStats) -> Result<()> {
        let LossIo { render, target, grad } = io;
        if pixels == 0 {
            bail!("high-frequency loss of an empty image");
        }
        if !(0.0..=1.0).contains(&pct) {
            bail!("high-frequency loss percentile {pct} is outside [0, 1]");
        }
        let need = 3 * pixels as usize;
        for b in [render, target, grad] {
            if b.len() < need {
                bail!("'{}' holds {} values; 3 planes of {pixels} pixels need {need}", b.name(), b.len());
            }
        }
        // Four passes over the pixels per invocation, plus the bin scans.
        if self.ctx.caps().is_cpu() && 4 * pixels.div_ceil(SELECT_WG) + 3 * 2048 > 60_000 {
            bail!("the high-frequency loss of {pixels} pixels exceeds a CPU driver's per-invocation loop budget");
        }
        rec.dispatch(&self.select, &[render.binding(), target.binding(), s.stats.binding()], bytemuck::cast_slice(&[pixels, pct.to_bits()]), [1, 1, 1])?;
        rec.dispatch(
            &self.grad,
            &[render.binding(), target.binding(), s.stats.binding(), grad.binding()],
            bytemuck::cast_slice(&[pixels, weight.to_bits()]),
            grid(&self.ctx, pixels),
        )?;
        rec.read_back(&s.stats, 0, &s.stats_host)
    }
}
