//! A trainable Gaussian set: parameters, their gradients, Adam moments and
//! the densification statistics, all on the GPU with the same SoA layout.

use crate::raster::{array_widths, Gaussians, HostGaussians, GAUSSIAN_ARRAYS};
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

    /// The names and widths (floats per Gaussian) of every per-Gaussian
    /// array of a set with `features` floats of features per Gaussian, in a
    /// fixed order: parameters, first moments, second moments, statistics.
    /// Checkpoints are laid out in this order.
    pub fn layout(features: usize) -> Vec<(String, usize)> {
        let mut out = Vec::new();
        for prefix in ["param", "adam_m", "adam_v"] {
            for (name, w) in GAUSSIAN_ARRAYS.into_iter().zip(array_widths(features)) {
                out.push((format!("{prefix}.{name}"), w));
            }
        }
        for name in ["stats.accum", "stats.denom", "stats.max_radii"] {
            out.push((name.to_string(), 1));
        }
        out
    }

    /// Every per-Gaussian array with its name and width, in [`Self::layout`] order.
    pub fn arrays(&self) -> Vec<(String, &Buffer<f32>, usize)> {
        let f = (self.params.channels * self.params.coeffs) as usize;
        let mut bufs = Vec::new();
        for g in [&self.params, &self.m, &self.v] {
            bufs.extend(g.buffers());
        }
        bufs.extend([&self.accum, &self.denom, &self.max_radii]);
        Self::layout(f).into_iter().zip(bufs).map(|((name, w), b)| (name, b, w)).collect()
    }
}
