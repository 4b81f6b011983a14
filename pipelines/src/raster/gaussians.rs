//! 2DGS Gaussian sets on the GPU, structure of arrays: means (3), log-scales
//! (2), quaternions (r, x, y, z), raw opacity (1, sigmoid) and a feature
//! block of `coeffs` x `channels` floats per Gaussian (coefficient-major:
//! element [k * channels + c]). Gradients use the same layout.

use anyhow::{bail, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context};

/// The names of a Gaussian set's five arrays, in the one order every list
/// of them follows (bindings, Adam groups, checkpoints, densification).
pub const GAUSSIAN_ARRAYS: [&str; 5] = ["means", "log_scales", "quats", "opacity", "features"];

/// Floats per Gaussian of each array, in [`GAUSSIAN_ARRAYS`] order, for a
/// set with `features` floats of features per Gaussian.
pub fn array_widths(features: usize) -> [usize; 5] {
    [3, 2, 4, 1, features]
}

/// A Gaussian set on the host (flat arrays in the GPU layout).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HostGaussians {
    pub channels: u32,
    pub coeffs: u32,
    pub means: Vec<f32>,
    pub log_scales: Vec<f32>,
    pub quats: Vec<f32>,
    pub opacity: Vec<f32>,
    pub features: Vec<f32>,
}

impl HostGaussians {
    pub fn new(channels: u32, coeffs: u32) -> Self {
        HostGaussians { channels, coeffs, ..Default::default() }
    }
    pub fn len(&self) -> usize {
        self.opacity.len()
    }
    pub fn is_empty(&self) -> bool {
        self.opacity.is_empty()
    }
    /// Append one Gaussian (`features`: coeffs x channels values).
    pub fn push(&mut self, mean: [f32; 3], log_scale: [f32; 2], quat: [f32; 4], opacity: f32, features: &[f32]) {
        self.means.extend_from_slice(&mean);
        self.log_scales.extend_from_slice(&log_scale);
        self.quats.extend_from_slice(&quat);
        self.opacity.push(opacity);
        self.features.extend_from_slice(features);
    }
    /// The set from its five arrays in [`GAUSSIAN_ARRAYS`] order.
    pub fn from_arrays(channels: u32, coeffs: u32, [means, log_scales, quats, opacity, features]: [Vec<f32>; 5]) -> Self {
        HostGaussians { channels, coeffs, means, log_scales, quats, opacity, features }
    }
    /// The five arrays in [`GAUSSIAN_ARRAYS`] order.
    pub fn arrays(&self) -> [&Vec<f32>; 5] {
        [&self.means, &self.log_scales, &self.quats, &self.opacity, &self.features]
    }
    pub fn validate(&self) -> Result<()> {
        let n = self.len();
        let fpg = (self.coeffs * self.channels) as usize;
        for ((name, a), w) in GAUSSIAN_ARRAYS.into_iter().zip(self.arrays()).zip(array_widths(fpg)) {
            let (got, want) = (a.len(), w * n);
            if got != want {
                bail!("Gaussian set: {name} has {got} values, expected {want} for {n} Gaussians");
            }
        }
        Ok(())
    }
}

/// A Gaussian set (or its gradient) on the GPU.
pub struct Gaussians {
    pub n: u32,
    pub channels: u32,
    pub coeffs: u32,
    pub means: Buffer<f32>,
    pub log_scales: Buffer<f32>,
    pub quats: Buffer<f32>,
    pub opacity: Buffer<f32>,
    pub features: Buffer<f32>,
}

impl Gaussians {
    /// Zero-initialised buffers for `n` Gaussians.
    pub fn zeros(ctx: &Arc<Context>, n: u32, channels: u32, coeffs: u32) -> Result<Gaussians> {
        Self::make(ctx, n, channels, coeffs, Buffer::new)
    }

    /// Buffers for `n` Gaussians with undefined contents, for callers that
    /// write every element before reading any (see [`Buffer::uninit`]).
    pub(crate) fn uninit(ctx: &Arc<Context>, n: u32, channels: u32, coeffs: u32) -> Result<Gaussians> {
        Self::make(ctx, n, channels, coeffs, Buffer::uninit)
    }

    fn make(ctx: &Arc<Context>, n: u32, channels: u32, coeffs: u32, alloc: fn(&Arc<Context>, &str, usize) -> Result<Buffer<f32>>) -> Result<Gaussians> {
        let m = n.max(1) as usize;
        let f = (coeffs * channels) as usize;
        Ok(Gaussians {
            n,
            channels,
            coeffs,
            means: alloc(ctx, "gaussians.means", 3 * m)?,
            log_scales: alloc(ctx, "gaussians.log_scales", 2 * m)?,
            quats: alloc(ctx, "gaussians.quats", 4 * m)?,
            opacity: alloc(ctx, "gaussians.opacity", m)?,
            features: alloc(ctx, "gaussians.features", f * m)?,
        })
    }

    pub fn upload(ctx: &Arc<Context>, h: &HostGaussians) -> Result<Gaussians> {
        h.validate()?;
        if h.is_empty() {
            return Self::zeros(ctx, 0, h.channels, h.coeffs);
        }
        // The uploads below write every element.
        let g = Self::uninit(ctx, h.len() as u32, h.channels, h.coeffs)?;
        for (buf, data) in g.buffers().into_iter().zip(h.arrays()) {
            buf.upload(data)?;
        }
        Ok(g)
    }

    pub fn download(&self) -> Result<HostGaussians> {
        let n = self.n as usize;
        let f = (self.coeffs * self.channels) as usize;
        let mut arrays: [Vec<f32>; 5] = Default::default();
        for ((a, buf), w) in arrays.iter_mut().zip(self.buffers()).zip(array_widths(f)) {
            *a = buf.download_range(0, w * n)?;
        }
        Ok(HostGaussians::from_arrays(self.channels, self.coeffs, arrays))
    }

    /// The five arrays in [`GAUSSIAN_ARRAYS`] order.
    pub fn buffers(&self) -> [&Buffer<f32>; 5] {
        [&self.means, &self.log_scales, &self.quats, &self.opacity, &self.features]
    }
}

/// What a rasterization draws: the Gaussians' geometry and opacity (`g`),
/// the per-Gaussian features that colour them (`g.features`, or a buffer
/// another kernel computed in the same layout: the reflection colour, the
/// light field's material) and the active SH degree (ignored for plain
/// features). The forward and backward of one view take the same.
#[derive(Clone, Copy)]
pub struct Splats<'a> {
    pub g: &'a Gaussians,
    pub features: &'a Buffer<f32>,
    pub sh_degree: u32,
}

impl<'a> Splats<'a> {
    /// `g` with its own features.
    pub fn own(g: &'a Gaussians, sh_degree: u32) -> Splats<'a> {
        Splats { g, features: &g.features, sh_degree }
    }
    /// `g` coloured by `features`, with no SH (degree 0).
    pub fn coloured(g: &'a Gaussians, features: &'a Buffer<f32>) -> Splats<'a> {
        Splats { g, features, sh_degree: 0 }
    }
}
