//! Stage III's light: the light-field network's parameters ([`MlpParams`]),
//! what every recording of one step shares, the reflection layer's forward,
//! and its part of the composite step Stages II and III share
//! (`stages/composite.rs`, [`Light`]).

use crate::train::config::TrainConfig;
use crate::train::stages::composite::{LayerIo, Light, LossTerms};
use crate::train::stages::rendered::R_PLANE;
use crate::train::stages::scattering::ExternalStep;
use crate::train::stages::scattering::ScatteringModel;
use anyhow::Result;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Readback, Recorder};
use tgs_pipelines::lightfield::CompositeGrads;
use tgs_pipelines::lightfield::{CompositeInputs, LightFieldShading, SampleScratch, ShadeParams, CHANNELS};
use tgs_pipelines::mlp::{Mlp, MlpScratch, MlpShape};
use tgs_pipelines::reflection::CompositePriors;
use tgs_pipelines::AdamArrays;
use tgs_pipelines::{Adam, AdamGroup, Camera, Frame, KeptWeights, Rasterizer, Splats, TrainableSet};

/// Stage III's light: the light-field network, with the reflection set's
/// material (its geometry frozen) and, when it trains, the scattering
/// set's colour (see [`Light`]).
pub(super) struct NetworkLight<'a> {
    pub(super) cfg: &'a TrainConfig,
    pub(super) cam: &'a Camera,
    pub(super) p: &'a Pass<'a>,
    pub(super) scattering: &'a ScatteringModel,
    /// The view's kept blend weights, which stand for its rasterization.
    pub(super) kept: Option<&'a KeptWeights>,
    pub(super) raster: &'a Rasterizer,
    pub(super) shading: &'a LightFieldShading,
    pub(super) mlp: &'a Mlp,
    pub(super) adam: &'a Adam,
    pub(super) set: &'a TrainableSet,
    pub(super) net: &'a MlpParams,
    pub(super) shade: &'a ShadeParams,
    pub(super) io: LayerIo<'a>,
    pub(super) scratch: &'a MlpScratch,
    pub(super) d_phi: &'a Buffer<f32>,
    pub(super) samples: &'a SampleScratch,
    pub(super) count_host: &'a Readback<u32>,
}

impl NetworkLight<'_> {
    fn inputs(&self) -> CompositeInputs<'_> {
        CompositeInputs { scat: self.p.scat, refl: &self.io.frame.out, samples: self.samples, phi: &self.scratch.out }
    }
}

impl Light for NetworkLight<'_> {
    const COMPOSITE: &'static str = "lf.composite";
    const COMPOSITE_BACKWARD: &'static str = "lf.composite_backward";

    fn record_forward(&mut self, rec: &mut Recorder) -> Result<()> {
        match self.p.host_count {
            Some(n) => self.mlp.record_forward(rec, &self.net.params, n, self.scratch),
            None => {
                let s = Splats::coloured(&self.set.params, self.io.feat);
                record_forward(rec, (self.shading, self.raster, self.kept), s, self.cam, self.shade, (self.io.frame, self.samples), self.scratch)?;
                self.mlp.record_forward_counted(rec, &self.net.params, &self.samples.count, self.scratch)
            }
        }
    }

    fn record_composite(&mut self, rec: &mut Recorder) -> Result<()> {
        self.shading.record_composite(rec, self.cam, self.shade, &self.inputs(), self.io.loss_in)
    }

    fn record_composite_backward(&mut self, rec: &mut Recorder) -> Result<()> {
        let cam = self.cam;
        let r_prior = CompositePriors::of_means(self.cfg.light_field.lambda_r, 0.0, cam.width * cam.height).r;
        let grads = CompositeGrads { loss_grad: self.io.loss_grad, d_phi: self.d_phi, refl_grad: &self.io.frame.grad_out, scat_grad: self.p.terms.scat_grad };
        self.shading.record_composite_backward(rec, cam, self.shade, &self.inputs(), &grads, r_prior)
    }

    fn record_update(&mut self, rec: &mut Recorder) -> Result<()> {
        let (cfg, p, cam) = (self.cfg, self.p, self.cam);
        if cfg.light_field.lambda_r > 0.0 {
            rec.read_back(&self.io.frame.out, R_PLANE * (cam.width * cam.height) as usize, self.io.r_host)?;
        }
        match p.host_count {
            Some(n) => self.mlp.record_backward(rec, &self.net.params, n, self.d_phi, &self.net.grads, self.scratch)?,
            None => self.mlp.record_backward_counted(rec, &self.net.params, &self.samples.count, self.d_phi, &self.net.grads, self.scratch)?,
        }
        // The reflection set's geometry is frozen: its material alone
        // needs gradients (from the view's kept weights, or the
        // feature-only tile backward).
        let s = Splats::coloured(&self.set.params, self.io.feat);
        match self.kept {
            Some(k) => self.raster.record_backward_colour_weights(rec, s, &self.set.grads, self.io.dfeat, self.io.frame, k)?,
            None => self.raster.record_backward_colour_with(rec, s, &self.set.grads, self.io.dfeat, self.io.frame)?,
        }
        let sc = rec.begin_scope("lf.material_backward");
        self.shading.record_material_backward(rec, &self.set.params.features, self.set.len(), self.io.dfeat, &self.set.grads.features)?;
        rec.end_scope(sc);
        if let Some(step) = &p.external {
            self.scattering.record_backward_external(rec, cfg, cam, step)?;
        }
        let (n, s) = (self.net, self.set);
        let np = n.shape.params() as usize;
        let net_arrays = AdamArrays { param: &n.params, grad: &n.grads, m: &n.m, v: &n.v, n: np };
        let material_arrays = AdamArrays { param: &s.params.features, grad: &s.grads.features, m: &s.m.features, v: &s.v.features, n: p.material_len };
        if p.host_count.is_some() {
            let sc = rec.begin_scope("adam");
            self.adam.record(rec, net_arrays, &p.net_group, p.it)?;
            self.adam.record(rec, material_arrays, &p.material_group, p.it)?;
            rec.end_scope(sc);
        } else {
            let args = self.raster.record_fit_gate(rec, self.io.frame, &[self.adam.grid(np), self.adam.grid(p.material_len)])?;
            let sc = rec.begin_scope("adam");
            self.adam.record_gated(rec, net_arrays, &p.net_group, p.it, &args[0])?;
            self.adam.record_gated(rec, material_arrays, &p.material_group, p.it, &args[1])?;
            rec.end_scope(sc);
            rec.read_back(&self.samples.count, 0, self.count_host)?;
        }
        Ok(())
    }
}

/// What every recording of one Stage III step shares (see
/// [`LightFieldModel::step`]).
pub(super) struct Pass<'a> {
    /// The scattering colour composited over.
    pub(super) scat: &'a Buffer<f32>,
    /// The sample count the host read (None: the GPU counts in the pass).
    pub(super) host_count: Option<u32>,
    /// The loss's terms (the scattering gradient among them).
    pub(super) terms: LossTerms<'a>,
    pub(super) it: u64,
    pub(super) net_group: AdamGroup,
    pub(super) material_group: AdamGroup,
    pub(super) material_len: usize,
    /// The scattering set's colour step, when it trains.
    pub(super) external: Option<ExternalStep>,
}

/// The MLP's parameters with their gradient and Adam moments.
pub struct MlpParams {
    pub shape: MlpShape,
    pub params: Buffer<f32>,
    pub grads: Buffer<f32>,
    pub m: Buffer<f32>,
    pub v: Buffer<f32>,
}

impl MlpParams {
    pub fn new(ctx: &Arc<Context>, shape: MlpShape, params: &[f32], m: &[f32], v: &[f32]) -> Result<MlpParams> {
        let n = shape.params() as usize;
        for (what, a) in [("parameters", params), ("first moments", m), ("second moments", v)] {
            if a.len() != n {
                anyhow::bail!("light-field {what}: {} values for a network of {n}", a.len());
            }
        }
        Ok(MlpParams {
            shape,
            params: Buffer::from_slice(ctx, "lf.params", params)?,
            grads: Buffer::new(ctx, "lf.grads", n)?,
            m: Buffer::from_slice(ctx, "lf.adam_m", m)?,
            v: Buffer::from_slice(ctx, "lf.adam_v", v)?,
        })
    }
}

/// Record the reflection set's material features (into `s.features`), its
/// rasterization into `frame` and the view's sample list (Phi's inputs,
/// `samples.count`), with the model's shading and raster kernels.
/// A training view's kept weights, where given, stand for the rasterization.
pub(super) fn record_forward(
    rec: &mut Recorder,
    (shading, raster, kept): (&LightFieldShading, &Rasterizer, Option<&KeptWeights>),
    s: Splats,
    cam: &Camera,
    shade: &ShadeParams,
    (frame, samples): (&Frame, &SampleScratch),
    scratch: &MlpScratch,
) -> Result<()> {
    let sc = rec.begin_scope("lf.material");
    shading.record_material(rec, &s.g.features, s.g.n, s.features)?;
    rec.end_scope(sc);
    let bg = [0.0; CHANNELS as usize];
    match kept {
        Some(k) => raster.record_forward_weights(rec, s, cam, &bg, frame, k)?,
        None => raster.record_forward_with(rec, s, cam, &bg, frame)?,
    }
    let sc = rec.begin_scope("lf.samples");
    shading.record_samples(rec, cam, shade, &frame.out, samples, &scratch.samples)?;
    rec.end_scope(sc);
    Ok(())
}
