//! The atomic-free backward of a view: per tile, back to front, one
//! gradient record per intersection; then a fixed-order per-Gaussian
//! reduction of those records fused with the projection backward.

use super::{Frame, Gaussians, Push, Rasterizer, Splats};
use anyhow::{bail, Result};
use tgs_engine::{groups_2d, Buffer, BufferBinding, Recorder};

impl Rasterizer {
    /// Record the backward of the last forward on `frame` (same Gaussians),
    /// with the loss gradient of every output plane in `frame.grad_out`.
    /// Overwrites every gradient in `grads` (and `frame.densify`).
    pub fn record_backward(&self, rec: &mut Recorder, g: &Gaussians, grads: &Gaussians, sh_degree: u32, frame: &Frame) -> Result<()> {
        self.record_own_backward(rec, g, grads, sh_degree, frame, false)
    }

    /// As [`Rasterizer::record_backward`] for a forward recorded with
    /// [`Rasterizer::record_forward_with`]: the feature gradients go to
    /// `d_features` (same layout as `features`), the geometry gradients to
    /// `grads` (whose own feature buffer is left alone).
    pub fn record_backward_with(&self, rec: &mut Recorder, s: Splats, grads: &Gaussians, d_features: &Buffer<f32>, frame: &Frame) -> Result<()> {
        self.record_backward_parts(rec, s, grads, d_features, frame, false)
    }

    /// As [`Rasterizer::record_backward`] for a set whose geometry does not
    /// train: the feature gradients, bit-identical to that backward's, at
    /// a fraction of its per-pixel work (the tile kernels form no geometric
    /// records). The other gradients in `grads` are partial (the colour's
    /// dependence on the view direction alone) and are not for stepping.
    pub fn record_backward_colour(&self, rec: &mut Recorder, g: &Gaussians, grads: &Gaussians, sh_degree: u32, frame: &Frame) -> Result<()> {
        self.record_own_backward(rec, g, grads, sh_degree, frame, true)
    }

    /// The backward of a set coloured by its own features (SH degree
    /// `sh`), its gradients in `grads`' own layout.
    fn record_own_backward(&self, rec: &mut Recorder, g: &Gaussians, grads: &Gaussians, sh: u32, frame: &Frame, colour_only: bool) -> Result<()> {
        if grads.channels != g.channels || grads.coeffs != g.coeffs {
            bail!("gradient buffers ({} x {} features) do not match the Gaussian set ({} x {})", grads.channels, grads.coeffs, g.channels, g.coeffs);
        }
        self.record_backward_parts(rec, Splats::own(g, sh), grads, &grads.features, frame, colour_only)
    }

    /// [`Rasterizer::record_backward_colour`] for a forward recorded with
    /// [`Rasterizer::record_forward_with`]: the feature gradients, those of
    /// [`Rasterizer::record_backward_with`] bit for bit, to `d_features`.
    pub fn record_backward_colour_with(&self, rec: &mut Recorder, s: Splats, grads: &Gaussians, d_features: &Buffer<f32>, frame: &Frame) -> Result<()> {
        self.record_backward_parts(rec, s, grads, d_features, frame, true)
    }

    fn record_backward_parts(&self, rec: &mut Recorder, s: Splats, grads: &Gaussians, d_features: &Buffer<f32>, frame: &Frame, colour_only: bool) -> Result<()> {
        let Splats { g, features, sh_degree } = s;
        if grads.n != g.n || d_features.len() < features.len().min((self.channels * self.features.coeffs() * g.n) as usize) {
            bail!("gradient buffers ({} Gaussians) do not match the Gaussian set ({})", grads.n, g.n);
        }
        let records = self.record_tile_backward(rec, g, features, sh_degree, frame, colour_only)?;
        self.record_reduce(rec, s, grads, d_features, frame, records)
    }

    /// The per-Gaussian reduce of the gradient records `records` (ranked by
    /// `frame.depth_ids`, ranges in `frame.offsets`) into `grads`.
    pub(super) fn record_reduce(&self, rec: &mut Recorder, s: Splats, grads: &Gaussians, d_features: &Buffer<f32>, frame: &Frame, records: BufferBinding) -> Result<()> {
        let Splats { g, features, sh_degree } = s;
        let sc = rec.begin_scope("raster.reduce");
        for slice in self.feature_slices(g.n) {
            let mut bindings = self.param_bindings(frame, g, features, slice);
            bindings.extend([
                frame.depth_ids.binding(),
                frame.offsets.binding(),
                records.clone(),
                grads.means.binding(),
                grads.log_scales.binding(),
                grads.quats.binding(),
                grads.opacity.binding(),
                self.feature_binding(d_features, slice),
                frame.densify.binding(),
            ]);
            let push = Push { feat_base: slice.0, feat_end: slice.1, ..self.push(g, frame, sh_degree) };
            rec.dispatch(&self.reduce, &bindings, bytemuck::bytes_of(&push), self.groups(g.n))?;
        }
        rec.end_scope(sc);
        Ok(())
    }

    /// The per-tile part of the backward (every span, back to front): the
    /// intersection gradient records (their feature entries only, the rest
    /// zero, with `colour_only`). Returns the records' binding for the
    /// per-Gaussian reduce.
    pub(super) fn record_tile_backward(
        &self,
        rec: &mut Recorder,
        g: &Gaussians,
        features: &Buffer<f32>,
        sh_degree: u32,
        frame: &Frame,
        colour_only: bool,
    ) -> Result<BufferBinding> {
        self.check_inputs(g, features, frame)?;
        let tk = self.tile_kernels(frame.tile)?;
        let kernel = if colour_only { tk.backward_colour()? } else { &tk.backward };
        let push = self.push(g, frame, sh_degree);
        let tile_groups = groups_2d(frame.tiles(), self.max_x());
        let mut bindings = Self::tile_bindings(frame);
        let records = match &frame.records_address {
            Some(a) => {
                // Reached through its address, not bound: keep it alive.
                rec.keep_alive(frame.isect_grads.binding());
                a.binding()
            }
            None => frame.isect_grads.binding(),
        };
        bindings.extend([frame.grad_out.binding(), frame.bstate.binding(), records.clone()]);
        for k in (0..frame.spans).rev() {
            let p = Push { span_index: k, ..push };
            let sc = rec.begin_scope("raster.backward");
            rec.dispatch(kernel, &bindings, bytemuck::bytes_of(&p), tile_groups)?;
            rec.end_scope(sc);
        }
        Ok(records)
    }

    /// Run the backward of the last [`Rasterizer::forward`] on `frame`.
    pub fn backward(&self, g: &Gaussians, grads: &Gaussians, sh_degree: u32, frame: &Frame, profile: bool) -> Result<Vec<tgs_engine::Timing>> {
        let mut rec = Recorder::profiled_if(&self.ctx, profile)?;
        self.record_backward(&mut rec, g, grads, sh_degree, frame)?;
        rec.submit_and_wait()
    }
}
