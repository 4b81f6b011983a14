//! A trainable Gaussian set: parameters, their gradients, Adam moments and
//! the densification statistics, all on the GPU with the same SoA layout.

use crate::raster::{Gaussians, HostGaussians};
use anyhow::Result;
use std::sync::Arc;
use tgs_engine::{Buffer, Context};

pub struct TrainableSet {
    pub params: Gaussians,
    pub grads: Gaussians,
    /// Adam first and second moments.
    pub m: Gaussians,
    pub v: Gaussians,
    /// Sum of screen-gradient norms, number of views seen, largest screen radius.
    pub accum: Buffer<f32>,
    pub denom: Buffer<f32>,
    pub max_radii: Buffer<f32>,
}

impl TrainableSet {
    /// A set with these parameters, zero moments and statistics.
    pub fn new(ctx: &Arc<Context>, h: &HostGaussians) -> Result<TrainableSet> {
        let params = Gaussians::upload(ctx, h)?;
        let (n, c, k) = (params.n, params.channels, params.coeffs);
        Self::from_parts(ctx, params, Gaussians::zeros(ctx, n, c, k)?, Gaussians::zeros(ctx, n, c, k)?)
    }

    /// A set from parameters and Adam moments; zero gradients and statistics.
    pub(crate) fn from_parts(ctx: &Arc<Context>, params: Gaussians, m: Gaussians, v: Gaussians) -> Result<TrainableSet> {
        let (n, c, k) = (params.n, params.channels, params.coeffs);
        let len = n.max(1) as usize;
        Ok(TrainableSet {
            grads: Gaussians::zeros(ctx, n, c, k)?,
            m,
            v,
            accum: Buffer::new(ctx, "set.accum", len)?,
            denom: Buffer::new(ctx, "set.denom", len)?,
            max_radii: Buffer::new(ctx, "set.max_radii", len)?,
            params,
        })
    }

    pub fn len(&self) -> u32 {
        self.params.n
    }
    pub fn is_empty(&self) -> bool {
        self.params.n == 0
    }

    /// Every per-Gaussian array with its width in floats, in a fixed order:
    /// parameters, first moments, second moments (checkpoints use it).
    pub fn arrays(&self) -> Vec<(String, &Buffer<f32>, usize)> {
        let f = (self.params.channels * self.params.coeffs) as usize;
        let mut out = Vec::new();
        for (prefix, g) in [("param", &self.params), ("adam_m", &self.m), ("adam_v", &self.v)] {
            out.push((format!("{prefix}.means"), &g.means, 3));
            out.push((format!("{prefix}.log_scales"), &g.log_scales, 2));
            out.push((format!("{prefix}.quats"), &g.quats, 4));
            out.push((format!("{prefix}.opacity"), &g.opacity, 1));
            out.push((format!("{prefix}.features"), &g.features, f));
        }
        out.push(("stats.accum".into(), &self.accum, 1));
        out.push(("stats.denom".into(), &self.denom, 1));
        out.push(("stats.max_radii".into(), &self.max_radii, 1));
        out
    }
}
