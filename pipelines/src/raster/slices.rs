//! A set whose features exceed one storage binding (a million Gaussians
//! of SH degree 3 are 183 MiB; lavapipe binds 128) is projected and
//! reduced in slices of Gaussians: each dispatch of the projection and of
//! the per-Gaussian reduce binds its slice's part of the features (and of
//! their moments or gradients) and takes the push constants
//! `feat_base` / `feat_end` (glsl/raster/common.glsl). The results are the
//! whole binding's, bit for bit (tests/tests/slices.rs). Adam's
//! own pass (`Adam::slice`) and the densification's copy
//! (`Densifier::slice`) slice their arrays likewise.

use super::{Frame, Gaussians, Rasterizer};
use tgs_engine::{Buffer, BufferBinding};

impl Rasterizer {
    /// Bindings 0..=5 of the projection and the reduce: the camera, the
    /// Gaussian parameters, and `slice`'s part of `features`.
    pub(super) fn param_bindings(&self, frame: &Frame, g: &Gaussians, features: &Buffer<f32>, slice: (u32, u32)) -> Vec<BufferBinding> {
        vec![frame.cam.binding(), g.means.binding(), g.log_scales.binding(), g.quats.binding(), g.opacity.binding(), self.feature_binding(features, slice)]
    }

    /// The slices [base, end) of Gaussians the per-Gaussian kernels that
    /// bind the features (the projection and the reduce) take in turn: one,
    /// every Gaussian with the whole buffers bound, unless `n` Gaussians'
    /// features exceed one storage binding (a million Gaussians of SH
    /// degree 3 are 183 MiB; lavapipe binds 128). Each slice then binds its
    /// own part of the features, and of their moments or gradients, and
    /// starts at a multiple of 64 Gaussians (so at an offset every device
    /// allows).
    pub(super) fn feature_slices(&self, n: u32) -> Vec<(u32, u32)> {
        let per = (4 * self.channels as u64 * self.features.coeffs() as u64).max(1);
        let max = self.ctx.caps().max_storage_buffer_range;
        match crate::slice_units(n as u64 * per <= max, max / per, self.feature_slice.map(u64::from)) {
            None => vec![(0, u32::MAX)],
            Some(slice) => {
                let slice = slice.min(u32::MAX as u64) as u32;
                (0..n.div_ceil(slice)).map(|k| (k * slice, ((k + 1) * slice).min(n))).collect()
            }
        }
    }

    /// This rasterizer with the Gaussians' features bound in slices of
    /// `gaussians` (rounded down to a multiple of 64; at most what one
    /// binding holds) even when they would fit one binding: tests compare
    /// the sliced projection and reduce with the whole ones on small sets.
    pub fn feature_slice(mut self, gaussians: u32) -> Rasterizer {
        self.feature_slice = Some(gaussians);
        self
    }

    /// `features`' binding for the slice (base, end) of
    /// [`Rasterizer::feature_slices`]: the whole buffer for the one slice
    /// of every Gaussian.
    pub(super) fn feature_binding(&self, features: &Buffer<f32>, slice: (u32, u32)) -> BufferBinding {
        if slice == (0, u32::MAX) {
            return features.binding();
        }
        let per = (self.channels * self.features.coeffs()) as usize;
        features.slice(slice.0 as usize * per, (slice.1 - slice.0) as usize * per)
    }
}
