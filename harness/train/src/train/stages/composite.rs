//! What Stages II and III share around their deferred composite
//! I = (1 - R) I_scat + R F Phi: the image loss of the composite (L1 +
//! D-SSIM, the normal term where the stage has one), the high-frequency
//! loss, the zeroed geometry planes of the scattering set's gradient (the
//! composite writes only its colour), and the step's loss value. Each
//! stage records its own composite and composite backward around these
//! (its light differs: a cube map, or the light-field network).

use anyhow::Result;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::{Camera, HfLoss, HfStats, ImageLoss, LossIo, LossScratch, LossValues, LossWeights};

/// A stage's high-frequency loss setting (`lambda_hf`, `hf_percentile` in
/// its section).
#[derive(Clone, Copy, Debug)]
pub struct HfSetting {
    pub lambda: f32,
    /// Percent (0..100) of the pixels' high-frequency error kept.
    pub percentile: f32,
}

/// The composite's losses (one per stage model).
pub struct CompositeLoss {
    image: ImageLoss,
    hf: HfLoss,
    hf_stats: HfStats,
}

impl CompositeLoss {
    pub fn new(ctx: &Arc<Context>) -> Result<CompositeLoss> {
        let hf = HfLoss::new(ctx)?;
        Ok(CompositeLoss { image: ImageLoss::new(ctx)?, hf_stats: hf.stats()?, hf })
    }

    /// Scratch for the image loss of a `w` x `h` composite.
    pub fn scratch(&self, w: u32, h: u32) -> Result<LossScratch> {
        self.image.scratch(w, h, 3)
    }

    /// Record the loss of the composite `io.render` (its planes, colour
    /// first) against `io.target`: its gradient into `io.grad`, the values
    /// into `s`.
    pub fn record(&self, rec: &mut Recorder, io: LossIo, cam: &Camera, w: &LossWeights, hf: HfSetting, s: &mut LossScratch) -> Result<()> {
        self.image.record_planes(rec, io, cam, w, s)?;
        if hf.lambda > 0.0 {
            let sc = rec.begin_scope("loss.hf");
            self.hf.record(rec, io, cam.width * cam.height, hf.percentile / 100.0, hf.lambda, &self.hf_stats)?;
            rec.end_scope(sc);
        }
        Ok(())
    }

    /// The scattering set's frame gradient `g` (of `pixels`) outside its
    /// colour planes set to zero: the composite writes only the colour,
    /// so the scattering geometry gets no gradient from it.
    pub fn clear_scattering_geometry(rec: &mut Recorder, g: &Buffer<f32>, pixels: usize) -> Result<()> {
        rec.fill(&g.slice(3 * pixels, g.len() - 3 * pixels), 0)
    }

    /// The step's loss from the image loss `values` (read after the
    /// submission): photometric, the normal term when weighted, the
    /// high-frequency term when on.
    pub fn value(&self, values: &LossValues, lambda_ssim: f32, w: &LossWeights, hf: HfSetting) -> Result<f64> {
        let mut loss = values.photometric(lambda_ssim as f64) + if w.normal != 0.0 { w.normal as f64 * values.normal } else { 0.0 };
        if hf.lambda > 0.0 {
            loss += hf.lambda as f64 * self.hf_stats.values()?.2;
        }
        Ok(loss)
    }
}
