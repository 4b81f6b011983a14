//! Fused Adam (PyTorch form) over one parameter buffer per dispatch.

use super::{grid, kernel};
use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use super::TrainableSet;
use tgs_engine::{Buffer, Context, Kernel, Recorder};

/// One parameter group: a learning rate, or two (elements with index modulo
/// `stride` below `split` use `lr`, the others `lr_rest`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamGroup {
    pub lr: f32,
    pub lr_rest: f32,
    pub stride: u32,
    pub split: u32,
}

impl AdamGroup {
    pub fn single(lr: f32) -> AdamGroup {
        AdamGroup { lr, lr_rest: lr, stride: 1, split: 1 }
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    n: u32,
    stride: u32,
    split: u32,
    pad: u32,
    lr_a: f32,
    lr_b: f32,
    beta1: f32,
    beta2: f32,
    eps: f32,
    bc1: f32,
    bc2: f32,
}

pub struct Adam {
    ctx: Arc<Context>,
    kernel: Kernel,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl Adam {
    /// Adam with betas (0.9, 0.999) and the given epsilon.
    pub fn new(ctx: &Arc<Context>, eps: f32) -> Result<Adam> {
        Ok(Adam { ctx: ctx.clone(), kernel: kernel(ctx, "adam", shaders::ADAM, std::mem::size_of::<Push>() as u32)?, beta1: 0.9, beta2: 0.999, eps })
    }

    /// Record step `t` (1-based) over the first `n` elements.
    #[allow(clippy::too_many_arguments)]
    pub fn record(&self, rec: &mut Recorder, param: &Buffer<f32>, grad: &Buffer<f32>, m: &Buffer<f32>, v: &Buffer<f32>, n: usize, group: &AdamGroup, t: u64) -> Result<()> {
        if n == 0 {
            return Ok(());
        }
        if [grad.len(), m.len(), v.len(), param.len()].iter().any(|&l| l < n) {
            bail!("Adam on '{}': {n} elements but a buffer is shorter", param.name());
        }
        if t == 0 || group.stride == 0 {
            bail!("Adam step must be >= 1 and stride >= 1");
        }
        let p = Push {
            n: n as u32,
            stride: group.stride,
            split: group.split,
            pad: 0,
            lr_a: group.lr,
            lr_b: group.lr_rest,
            beta1: self.beta1,
            beta2: self.beta2,
            eps: self.eps,
            bc1: 1.0 - self.beta1.powf(t as f32),
            bc2: 1.0 - self.beta2.powf(t as f32),
        };
        rec.dispatch(&self.kernel, &[param.binding(), grad.binding(), m.binding(), v.binding()], bytemuck::bytes_of(&p), grid(&self.ctx, n as u32))
    }

    /// Record step `t` over every parameter array of `set`, in its layout
    /// order (means, log-scales, quaternions, opacity, features), each with
    /// its group.
    pub fn record_set(&self, rec: &mut Recorder, set: &TrainableSet, groups: &[AdamGroup; 5], t: u64) -> Result<()> {
        let n = set.len() as usize;
        let f = (set.params.channels * set.params.coeffs) as usize;
        let (p, g, m, v) = (&set.params, &set.grads, &set.m, &set.v);
        let arrays = [
            (&p.means, &g.means, &m.means, &v.means, 3 * n),
            (&p.log_scales, &g.log_scales, &m.log_scales, &v.log_scales, 2 * n),
            (&p.quats, &g.quats, &m.quats, &v.quats, 4 * n),
            (&p.opacity, &g.opacity, &m.opacity, &v.opacity, n),
            (&p.features, &g.features, &m.features, &v.features, f * n),
        ];
        for ((p, g, m, v, len), group) in arrays.into_iter().zip(groups) {
            self.record(rec, p, g, m, v, len, group, t)?;
        }
        Ok(())
    }
}
