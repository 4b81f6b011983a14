//! What Stages II and III share around their deferred composite
//! I = (1 - R) I_scat + R F Phi: one recording of a step
//! ([`record_composite_step`]: the forward, the composite, its image loss
//! (L1 + D-SSIM, the normal term where the stage has one) and
//! high-frequency loss, the zeroed geometry planes of the scattering set's
//! gradient (the composite writes only its colour), the composite's
//! backward and the update), and the step's loss value. What differs is
//! the [`Light`]: a cube map (Stage II) or the light-field network (Stage
//! III), with what trains beside it.

use anyhow::Result;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Readback, Recorder};
use tgs_pipelines::{Camera, Frame, HfLoss, HfStats, ImageLoss, LossIo, LossScratch, LossValues, LossWeights, Plane};

/// What a later stage records around the shared composite step: its
/// reflection layer's forward, the composite with its light, the
/// composite's backward, and the update of what it trains.
pub trait Light {
    /// The scope names of its composite and composite backward (GPU timings).
    const COMPOSITE: &'static str;
    const COMPOSITE_BACKWARD: &'static str;
    /// The reflection layer's forward (and the light's) for this pass.
    fn record_forward(&mut self, rec: &mut Recorder) -> Result<()>;
    /// The composite into the loss's input.
    fn record_composite(&mut self, rec: &mut Recorder) -> Result<()>;
    /// The composite's backward from the loss gradient.
    fn record_composite_backward(&mut self, rec: &mut Recorder) -> Result<()>;
    /// Everything after: read-backs, the light's and the sets' backward, Adam.
    fn record_update(&mut self, rec: &mut Recorder) -> Result<()>;
}

/// A pass's loss terms: the image loss's weights, the high-frequency
/// setting, and the scattering set's frame gradient when its colour trains.
#[derive(Clone, Copy)]
pub struct LossTerms<'a> {
    pub weights: LossWeights,
    pub hf: HfSetting,
    pub scat_grad: Option<&'a Buffer<f32>>,
}

/// A step's image loss: the composite (`io.render`) against the target,
/// its gradient into `io.grad`, the values into `scratch`, with the pass's
/// terms.
pub struct StepLoss<'a> {
    pub loss: &'a CompositeLoss,
    pub io: LossIo<'a>,
    pub scratch: &'a mut LossScratch,
    pub cam: &'a Camera,
    pub terms: LossTerms<'a>,
}

/// A view size's buffers of a later stage's step: the reflection layer's
/// frame, the image loss's scratch, the composite (the loss's input), its
/// gradient, and the R plane brought back when the stage's `lambda_r` > 0.
pub struct StepBuffers {
    pub frame: Frame,
    pub loss: LossScratch,
    pub loss_in: Buffer<f32>,
    pub loss_grad: Buffer<f32>,
    pub r_host: Readback<f32>,
}

/// What the light reads and writes of a step's buffers: the reflection
/// set's rasterized features and their gradient, the frame, the
/// composite, its gradient and the R plane's read-back.
pub struct LayerIo<'a> {
    pub feat: &'a Buffer<f32>,
    pub dfeat: &'a Buffer<f32>,
    pub frame: &'a Frame,
    pub loss_in: &'a Buffer<f32>,
    pub loss_grad: &'a Buffer<f32>,
    pub r_host: &'a Readback<f32>,
}

impl StepBuffers {
    /// Buffers for `frame`'s size, named `{stage}.loss_in` and so on.
    pub fn new(ctx: &Arc<Context>, objective: &CompositeLoss, frame: Frame, stage: &str) -> Result<StepBuffers> {
        let (w, h) = (frame.width, frame.height);
        let planes = (Plane::count(3) * w * h) as usize;
        Ok(StepBuffers {
            frame,
            loss: objective.scratch(w, h)?,
            loss_in: Buffer::new(ctx, &format!("{stage}.loss_in"), planes)?,
            loss_grad: Buffer::new(ctx, &format!("{stage}.loss_grad"), planes)?,
            r_host: Readback::new(ctx, &format!("{stage}.r_host"), (w * h) as usize)?,
        })
    }

    /// The step's loss (the composite `loss_in` against `target`, with the
    /// pass's `terms`) and what the light uses, `feat` and `dfeat` with it.
    pub fn split<'a>(
        &'a mut self,
        objective: &'a CompositeLoss,
        target: &'a Buffer<f32>,
        cam: &'a Camera,
        terms: LossTerms<'a>,
        (feat, dfeat): (&'a Buffer<f32>, &'a Buffer<f32>),
    ) -> (StepLoss<'a>, LayerIo<'a>) {
        let StepBuffers { frame, loss, loss_in, loss_grad, r_host } = self;
        let step = StepLoss { loss: objective, io: LossIo { render: loss_in, target, grad: loss_grad }, scratch: loss, cam, terms };
        (step, LayerIo { feat, dfeat, frame, loss_in, loss_grad, r_host })
    }
}

/// One recording of a later stage's step: `light`'s forward, its composite,
/// the loss, the composite's backward (after zeroing the scattering
/// gradient's geometry planes) and `light`'s update.
pub fn record_composite_step<L: Light>(rec: &mut Recorder, light: &mut L, l: StepLoss) -> Result<()> {
    light.record_forward(rec)?;
    let sc = rec.begin_scope(L::COMPOSITE);
    light.record_composite(rec)?;
    rec.end_scope(sc);
    l.loss.record(rec, l.io, l.cam, &l.terms.weights, l.terms.hf, l.scratch)?;
    let sc = rec.begin_scope(L::COMPOSITE_BACKWARD);
    if let Some(g) = l.terms.scat_grad {
        // The composite writes the colour planes; the scattering geometry
        // planes get no gradient.
        CompositeLoss::clear_scattering_geometry(rec, g, (l.cam.width * l.cam.height) as usize)?;
    }
    light.record_composite_backward(rec)?;
    rec.end_scope(sc);
    light.record_update(rec)
}

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
