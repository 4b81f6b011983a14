//! Stage II's light: the cube map, what every recording of one step shares,
//! the reflection layer's forward, and its part of the composite step
//! Stages II and III share (`stages/composite.rs`, [`Light`]).

use super::masks::GlassMask;
use super::settings::RotationGrad;
use crate::train::config::TrainConfig;
use crate::train::stages::composite::{LayerIo, Light, LossTerms};
use crate::train::stages::rendered::R_PLANE;
use crate::train::stages::scattering::ExternalStep;
use crate::train::stages::scattering::ScatteringModel;
use anyhow::Result;
use tgs_engine::{Buffer, Readback, Recorder};
use tgs_pipelines::reflection::CompositeGrads;
use tgs_pipelines::reflection::CompositePriors;
use tgs_pipelines::reflection::{ColorInputs, CompositeInputs, TexelScratch};
use tgs_pipelines::AdamArrays;
use tgs_pipelines::Splats;
use tgs_pipelines::{Adam, AdamGroup, Camera, EnvMap, Frame, Fresnel, Plane, Rasterizer, ReflectionShading, TrainableSet};

/// Stage II's light: the cube map, with the reflection set's geometry,
/// material and the map itself training (see [`Light`]).
pub(super) struct CubeMapLight<'a> {
    pub(super) cfg: &'a TrainConfig,
    pub(super) cam: &'a Camera,
    pub(super) p: &'a Pass<'a>,
    pub(super) raster: &'a Rasterizer,
    pub(super) shading: &'a ReflectionShading,
    pub(super) adam: &'a Adam,
    pub(super) fresnel: Fresnel,
    pub(super) set: &'a TrainableSet,
    pub(super) env: &'a EnvMap,
    pub(super) io: LayerIo<'a>,
    pub(super) texels: &'a TexelScratch,
    pub(super) alpha_host: &'a Readback<f32>,
    /// The view's glass mask when `reflection.lambda_mask` weighs it (ReflectionModel::step).
    pub(super) mask: Option<&'a GlassMask>,
}

impl Light for CubeMapLight<'_> {
    const COMPOSITE: &'static str = "refl.composite";
    const COMPOSITE_BACKWARD: &'static str = "refl.composite_backward";

    fn record_forward(&mut self, rec: &mut Recorder) -> Result<()> {
        let cam = self.cam;
        record_forward(rec, (self.shading, self.raster), &ColorInputs { g: &self.set.params, env: self.env, cam, fresnel: self.fresnel }, self.io.feat, self.io.frame)
    }

    fn record_composite(&mut self, rec: &mut Recorder) -> Result<()> {
        self.shading.record_composite(rec, self.cam, self.fresnel, &CompositeInputs { scat: self.p.scat, refl: &self.io.frame.out }, self.io.loss_in)
    }

    fn record_composite_backward(&mut self, rec: &mut Recorder) -> Result<()> {
        let rc = &self.cfg.reflection;
        let cam = self.cam;
        let prior = CompositePriors::of_means(rc.lambda_r, rc.lambda_area, cam.width * cam.height).with_mask(rc.lambda_mask, cam.width * cam.height);
        let mask = self.mask.map(|m| &m.gpu);
        let g = CompositeGrads { loss_grad: self.io.loss_grad, refl_grad: &self.io.frame.grad_out, scat_grad: self.p.terms.scat_grad, mask };
        self.shading.record_composite_backward(rec, cam, self.fresnel, &CompositeInputs { scat: self.p.scat, refl: &self.io.frame.out }, &g, prior)
    }

    fn record_update(&mut self, rec: &mut Recorder) -> Result<()> {
        let (cfg, p, cam) = (self.cfg, self.p, self.cam);
        let rc = &cfg.reflection;
        let n = (cam.width * cam.height) as usize;
        if rc.lambda_r > 0.0 {
            rec.read_back(&self.io.frame.out, R_PLANE * n, self.io.r_host)?;
        }
        if rc.lambda_area > 0.0 || self.mask.is_some() {
            rec.read_back(&self.io.frame.out, Plane::Alpha.index(self.fresnel.channels()) as usize * n, self.alpha_host)?;
        }
        if let Some((m, step)) = &p.external {
            m.record_backward_external(rec, cfg, cam, step)?;
        }
        self.raster.record_backward_with(rec, Splats::coloured(&self.set.params, self.io.feat), &self.set.grads, self.io.dfeat, self.io.frame)?;
        if rc.rotation_grad == RotationGrad::Reflection {
            // The colour's backward adds the mirror direction's part to zeros.
            rec.fill(&self.set.grads.quats.binding(), 0)?;
        }
        let sc = rec.begin_scope("refl.color_backward");
        let inputs = ColorInputs { g: &self.set.params, env: self.env, cam, fresnel: self.fresnel };
        self.shading.record_color_backward(rec, &inputs, self.io.dfeat, &self.set.grads, self.texels)?;
        rec.end_scope(sc);
        let e = self.env;
        let mut grids = self.adam.set_grids(self.set, &p.groups).to_vec();
        grids.push(self.adam.grid(e.len()));
        let args = self.raster.record_fit_gate(rec, self.io.frame, &grids)?;
        let sc = rec.begin_scope("adam");
        self.adam.record_set_gated(rec, self.set, &p.groups, p.it, &args[..5])?;
        self.adam.record_gated(rec, AdamArrays { param: &e.params, grad: &e.grads, m: &e.m, v: &e.v, n: e.len() }, &AdamGroup::single(rc.lr_env), p.it, &args[5])?;
        rec.end_scope(sc);
        Ok(())
    }
}

/// What every recording of one Stage II step shares (see
/// [`ReflectionModel::step`]).
pub(super) struct Pass<'a> {
    /// The scattering colour composited over.
    pub(super) scat: &'a Buffer<f32>,
    /// The trained scattering model and its colour's step, when it trains.
    pub(super) external: Option<(&'a ScatteringModel, ExternalStep)>,
    /// The loss's terms (the scattering gradient among them).
    pub(super) terms: LossTerms<'a>,
    pub(super) groups: [AdamGroup; 5],
    pub(super) it: u64,
}

/// Record the reflection colour of every Gaussian of `x.g` seen from
/// `x.cam` into `feat` and the rasterization of [colour, r (, f0)] into
/// `frame`, with the model's colour and raster kernels.
pub(super) fn record_forward(rec: &mut Recorder, (shading, raster): (&ReflectionShading, &Rasterizer), x: &ColorInputs, feat: &Buffer<f32>, frame: &Frame) -> Result<()> {
    let sc = rec.begin_scope("refl.color");
    shading.record_color(rec, x, feat)?;
    rec.end_scope(sc);
    let bg = vec![0.0; x.fresnel.channels() as usize];
    raster.record_forward_with(rec, Splats::coloured(x.g, feat), x.cam, &bg, frame)
}
