//! Stage III's model (paper §3.4, method-notes §3.5): the reflection light
//! field Phi(x, w), an MLP on Fourier features of the reflection point and
//! direction, replacing Stage II's environment map. The reflection set's
//! geometry is frozen (its material f0, r trains); the scattering set
//! trains with it unless `light_field.train_scattering` is off. Per view:
//! the reflection render of [F0 sum, R], the list of pixels with
//! R > threshold (Phi runs on those only), the MLP, the composite
//! I = (1 - R) S + R F Phi, L1 + D-SSIM, and the backward through all of
//! it. Never refers to the trainer.

pub use super::light::MlpParams;
use super::light::{record_forward, NetworkLight, Pass};
use crate::train::config::TrainConfig;
use crate::train::stages::composite::{record_composite_step, CompositeLoss, HfSetting, LossTerms, StepBuffers};
use crate::train::stages::kept_views::{KeepAs, KeptViews};
use crate::train::stages::rendered::{PhiLayers, ReflRendered};
use crate::train::stages::scattering::ExternalStep;
use crate::train::stages::scattering::{ScatteringModel, StepOutput};
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Readback, Recorder, Timing};
use tgs_pipelines::lightfield::{CompositeInputs, LightFieldShading, SampleScratch, ShadeParams, CHANNELS};
use tgs_pipelines::mlp::{Mlp, MlpScratch, MlpShape, OUT};
use tgs_pipelines::reflection::MATERIAL;
use tgs_pipelines::{Adam, AdamGroup, Camera, Features, LossWeights, Plane, Rasterizer, Splats, TrainableSet};

/// What the trainer passes for one Stage III step.
pub struct LightFieldStepInput<'a> {
    /// Iteration within Stage III (1-based): the MLP's Adam step.
    pub iteration: u32,
    /// Global iteration: the scattering set's Adam step.
    pub global_iteration: u32,
    pub camera: &'a Camera,
    /// The training view, and the budget of each set's kept blend weights.
    pub keep: KeepAs,
    pub target: &'a Buffer<f32>,
    /// The frozen scattering colour of this view when the scattering set
    /// does not train.
    pub scat: Option<&'a Buffer<f32>>,
    pub sh_degree: u32,
    pub background: [f32; 3],
    /// Scattering position rate (scaled by the extent).
    pub lr_means: f32,
    pub profile: bool,
}

struct ViewBuffers {
    samples: SampleScratch,
    step: StepBuffers,
}

pub struct LightFieldModel {
    ctx: Arc<Context>,
    raster: Rasterizer,
    shading: LightFieldShading,
    mlp: Mlp,
    objective: CompositeLoss,
    adam: Adam,
    /// The reflection set (geometry frozen, material trained).
    pub set: TrainableSet,
    pub net: MlpParams,
    /// Normalization box, threshold and Fresnel switch.
    pub shade: ShadeParams,
    feat: Buffer<f32>,
    dfeat: Buffer<f32>,
    scratch: Option<MlpScratch>,
    d_phi: Option<Buffer<f32>>,
    sizes: HashMap<(u32, u32), ViewBuffers>,
    /// Samples evaluated and pixels seen since the last `take_coverage`.
    evaluated: (u64, u64),
    /// The sample count of the last one-submission step, ridden back.
    count_host: Readback<u32>,
    /// Steps may be one submission (see [`LightFieldModel::step`]); off,
    /// the host reads every view's sample count first (the same results,
    /// bit for bit: tests/tests/train_step.rs compares them).
    pub one_submission: bool,
    /// Training views' blend weights and geometry planes of the reflection
    /// set (its geometry is frozen in Stage III).
    kept: KeptViews,
}

impl LightFieldModel {
    /// Stage III from the reflection set `set` (its Adam moments kept) and a
    /// network `net`; `shade` fixes the normalization box.
    pub fn new(ctx: &Arc<Context>, set: TrainableSet, net: MlpParams, shade: ShadeParams, adam_eps: f32) -> Result<LightFieldModel> {
        let n = set.len().max(1) as usize;
        let ch = CHANNELS as usize;
        Ok(LightFieldModel {
            raster: Rasterizer::new(ctx, CHANNELS, Features::Plain)?,
            shading: LightFieldShading::new(ctx)?,
            mlp: Mlp::new(ctx)?,
            objective: CompositeLoss::new(ctx)?,
            adam: Adam::new(ctx, adam_eps)?,
            set,
            net,
            shade,
            feat: Buffer::uninit(ctx, "lf.features", ch * n)?,
            dfeat: Buffer::uninit(ctx, "lf.d_features", ch * n)?,
            scratch: None,
            d_phi: None,
            sizes: HashMap::new(),
            evaluated: (0, 0),
            count_host: Readback::new(ctx, "lf.count_host", 1)?,
            one_submission: true,
            kept: KeptViews::default(),
            ctx: ctx.clone(),
        })
    }

    /// A fresh network of `shape` (PyTorch's default initialisation).
    pub fn init_net(ctx: &Arc<Context>, shape: MlpShape, seed: u64) -> Result<MlpParams> {
        let zeros = vec![0.0; shape.params() as usize];
        MlpParams::new(ctx, shape, &shape.init_params(seed), &zeros, &zeros)
    }

    fn view_buffers(&mut self, w: u32, h: u32) -> Result<()> {
        let pixels = w * h;
        // One sample per pixel at most; the MLP takes them in blocks when
        // their activations exceed one binding (then the step reads the
        // sample count on the host: `step`).
        let cap = pixels;
        if self.scratch.as_ref().is_none_or(|s| s.capacity() < cap) {
            self.scratch = Some(self.mlp.scratch(self.net.shape, cap)?);
            self.d_phi = Some(Buffer::uninit(&self.ctx, "lf.d_phi", (OUT * cap) as usize)?);
        }
        if !self.sizes.contains_key(&(w, h)) {
            let n = self.set.len();
            let max_g = n + 1024;
            let frame = self.raster.frame(w, h, max_g, self.raster.initial_capacity(max_g))?;
            let samples = self.shading.sample_scratch(w, h)?;
            let vb = ViewBuffers { samples, step: StepBuffers::new(&self.ctx, &self.objective, frame, "lf")? };
            self.sizes.insert((w, h), vb);
        }
        Ok(())
    }

    /// Reflection render + sample list of `cam`, re-run until the frame
    /// fits; returns the number of samples.
    /// A training view (`keep`) uses and keeps its blend weights.
    fn forward(&mut self, cam: &Camera, keep: Option<KeepAs>, profile: bool, timings: &mut Vec<Timing>) -> Result<u32> {
        self.view_buffers(cam.width, cam.height)?;
        let b = self.sizes.get_mut(&(cam.width, cam.height)).context("light-field view buffers")?;
        let scratch = self.scratch.as_ref().context("light-field scratch")?;
        let kept = keep.and_then(|k| self.kept.get(k.view));
        loop {
            let mut rec = Recorder::profiled_if(&self.ctx, profile)?;
            record_forward(&mut rec, (&self.shading, &self.raster, kept), Splats::coloured(&self.set.params, &self.feat), cam, &self.shade, (&b.step.frame, &b.samples), scratch)?;
            timings.extend(rec.submit_and_wait()?);
            if self.raster.fit(&mut b.step.frame)? {
                break;
            }
            if kept.is_some() {
                bail!("a training view's render from its kept weights did not fit its frame");
            }
        }
        if let (Some(at), None) = (keep, kept) {
            let (raster, set) = (&self.raster, &self.set);
            self.kept.capture(at, |budget| raster.keep_weights(&set.params, &b.step.frame, budget, true));
        }
        let count = b.samples.count.download()?[0];
        if count > scratch.capacity() {
            bail!("a {}x{} view has {count} light-field samples; its sample list holds {}", cam.width, cam.height, scratch.capacity());
        }
        Ok(count)
    }

    /// The kernel the MLP runs on (`TGS_MLP_GEMM` chooses; the results
    /// are the same bits on each).
    pub fn mlp_kernel(&self) -> &'static str {
        self.mlp.gemm().name()
    }

    /// Samples the light field takes in one pass (0 before the first view).
    pub fn mlp_block(&self) -> u32 {
        self.scratch.as_ref().map_or(0, |s| s.block())
    }

    /// Fraction of pixels Phi was evaluated at since the last call.
    pub fn take_coverage(&mut self) -> Option<f64> {
        let (s, p) = std::mem::take(&mut self.evaluated);
        (p > 0).then(|| s as f64 / p as f64)
    }

    /// The MLP's learning rate at Stage III iteration `it` (of `light_field.iterations`).
    pub fn lr(cfg: &TrainConfig, it: u32) -> f32 {
        let lf = &cfg.light_field;
        crate::train::log_lerp(lf.lr, lf.lr_final, it as f64 / lf.iterations.max(1) as f64) as f32
    }

    /// One Stage III step on one view. With the scattering set frozen (the
    /// default) and room in the sample list for every pixel, the step is
    /// one submission: the reflection render, the sample list, the MLP on
    /// the GPU's sample count, the composite, the losses, the backward and
    /// Adam (gated on the frame having fitted; a view that overflowed
    /// updates nothing and runs again after its frame grew). Otherwise the
    /// forward is its own submission: the scattering set's render, or the
    /// sample count the host must check against the list's capacity.
    pub fn step(&mut self, cfg: &TrainConfig, scattering: &mut ScatteringModel, x: &LightFieldStepInput) -> Result<StepOutput> {
        let cam = x.camera;
        let mut timings = Vec::new();
        let train_scat = x.scat.is_none();
        let colour_only = cfg.light_field.scattering_colour_only();
        if train_scat && colour_only {
            timings.extend(scattering.forward_view_kept(x.keep, cam, x.sh_degree, &x.background, x.profile)?);
        } else if train_scat {
            timings.extend(scattering.forward_view(cam, x.sh_degree, &x.background, x.profile)?);
        }
        self.view_buffers(cam.width, cam.height)?;
        let pixels = cam.width * cam.height;
        // The GPU-count step needs every pixel's sample within one block.
        let room = self.scratch.as_ref().is_some_and(|s| s.block() >= pixels);
        // A view whose weights would be captured renders in full in its
        // own submission first, and they are captured for the backward.
        let unkept = self.kept.would_capture(x.keep);
        let host_count = if train_scat || !room || !self.one_submission || unkept { Some(self.forward(cam, Some(x.keep), x.profile, &mut timings)?) } else { None };
        let (scat, scat_grad) = match x.scat {
            Some(s) => (s, None),
            None => {
                let (out, grad) = scattering.frame_buffers(cam.width, cam.height)?;
                (out, Some(grad))
            }
        };
        let weights = LossWeights { ssim: cfg.lambda_ssim, normal: 0.0, dist: 0.0 };
        let lf = &cfg.light_field;
        let it = x.iteration as u64;
        let net_group = AdamGroup::single(Self::lr(cfg, x.iteration));
        // Material only: f0 (3) at lr_f0, r at lr_r; the geometry is frozen.
        let material_len = (MATERIAL * self.set.len()) as usize;
        let material_group = AdamGroup::split(lf.lr_f0, lf.lr_r, MATERIAL, 3);
        let kept = self.kept.get(x.keep.view).is_some();
        let external = train_scat.then_some(ExternalStep { sh_degree: x.sh_degree, lr_means: x.lr_means, iteration: x.global_iteration, colour_only });
        let hf = HfSetting { lambda: lf.lambda_hf, percentile: lf.hf_percentile };
        let pass = Pass { scat, terms: LossTerms { weights, hf, scat_grad }, host_count, it, net_group, material_group, material_len, external };
        loop {
            let mut rec = Recorder::profiled_if(&self.ctx, x.profile)?;
            self.record_pass(&mut rec, cfg, scattering, x, &pass)?;
            timings.extend(rec.submit_and_wait()?);
            let b = self.sizes.get_mut(&(cam.width, cam.height)).context("light-field view buffers")?;
            if host_count.is_some() || self.raster.fit(&mut b.step.frame)? {
                break;
            }
            if kept {
                bail!("a training view's render from its kept weights did not fit its frame");
            }
        }
        let count = match host_count {
            Some(n) => n,
            None => self.count_host.read()?[0],
        };
        self.evaluated.0 += count as u64;
        self.evaluated.1 += (cam.width * cam.height) as u64;
        let b = &self.sizes[&(cam.width, cam.height)].step;
        let values = b.loss.values()?;
        let mut loss = self.objective.value(&values, cfg.lambda_ssim, &weights, hf)?;
        if lf.lambda_r > 0.0 {
            loss += lf.lambda_r as f64 * crate::train::mean(&b.r_host.read()?);
        }
        Ok(StepOutput { loss, values, densified: None, timings })
    }

    /// One recording of a Stage III step (see [`Self::step`]): the shared
    /// composite step around the network's [`NetworkLight`].
    fn record_pass(&mut self, rec: &mut Recorder, cfg: &TrainConfig, scattering: &ScatteringModel, x: &LightFieldStepInput, p: &Pass<'_>) -> Result<()> {
        let cam = x.camera;
        let LightFieldModel { raster, shading, mlp, objective, adam, set, net, shade, feat, dfeat, scratch, d_phi, sizes, count_host, kept, .. } = self;
        let ViewBuffers { samples, step } = sizes.get_mut(&(cam.width, cam.height)).context("light-field view buffers")?;
        let (step, io) = step.split(objective, x.target, cam, p.terms, (feat, dfeat));
        let mut light = NetworkLight {
            cfg,
            cam,
            p,
            scattering,
            kept: kept.get(x.keep.view),
            raster,
            shading,
            mlp,
            adam,
            set,
            net,
            shade,
            io,
            scratch: scratch.as_ref().context("light-field scratch")?,
            d_phi: d_phi.as_ref().context("light-field gradient buffer")?,
            samples,
            count_host,
        };
        record_composite_step(rec, &mut light, step)
    }

    /// Render `cam` composited over the scattering colour `scat` (3 planes).
    pub fn render(&mut self, cam: &Camera, scat: &Buffer<f32>) -> Result<ReflRendered> {
        let mut timings = Vec::new();
        let count = self.forward(cam, None, false, &mut timings)?;
        let b = &self.sizes[&(cam.width, cam.height)];
        let scratch = self.scratch.as_ref().context("light-field scratch")?;
        let mut rec = Recorder::new(&self.ctx)?;
        self.mlp.record_forward(&mut rec, &self.net.params, count, scratch)?;
        let (samples, b) = (&b.samples, &b.step);
        self.shading.record_composite(&mut rec, cam, &self.shade, &CompositeInputs { scat, refl: &b.frame.out, samples, phi: &scratch.out }, &b.loss_in)?;
        rec.submit_and_wait()?;
        let n = (cam.width * cam.height) as usize;
        let composite = b.loss_in.download()?;
        let refl = b.frame.out.download()?;
        let sample_of = samples.sample_of.download()?;
        let phi = if count > 0 { scratch.out.download_range(0, (OUT * count) as usize)? } else { Vec::new() };
        // F Phi per pixel (the composite kernel's F, recomputed on the host).
        let mut reflected = vec![0.0; 3 * n];
        let mut mask = vec![0.0; n];
        let alpha = &refl[CHANNELS as usize * n..(CHANNELS as usize + 1) * n];
        for i in 0..n {
            let s = sample_of[i];
            if s == u32::MAX {
                continue;
            }
            mask[i] = 1.0;
            let f0 = |c: usize| refl[c * n + i] / alpha[i].max(1e-6);
            let m = if self.shade.schlick {
                let cos = pixel_cos(cam, i, &refl, n);
                (1.0 - cos.clamp(0.0, 1.0)).powi(5)
            } else {
                0.0
            };
            for c in 0..3 {
                let f = f0(c) + (1.0 - f0(c)) * m;
                reflected[c * n + i] = f * phi[3 * s as usize + c];
            }
        }
        Ok(ReflRendered { width: cam.width, height: cam.height, composite, refl, channels: CHANNELS, phi: Some(PhiLayers { reflected, mask }) })
    }
}

/// n . v at pixel `i` of a reflection render (1 without a normal).
fn pixel_cos(cam: &Camera, i: usize, refl: &[f32], n: usize) -> f32 {
    let (x, y) = ((i % cam.width as usize) as f32, (i / cam.width as usize) as f32);
    let ray = [(x - cam.cx) / cam.fx, (y - cam.cy) / cam.fy, 1.0];
    let l = (ray[0] * ray[0] + ray[1] * ray[1] + 1.0).sqrt();
    let nn: Vec<f32> = (0..3).map(|k| refl[Plane::Normal(k).index(CHANNELS) as usize * n + i]).collect();
    let nl = (nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]).sqrt();
    if nl <= 1e-12 {
        return 1.0;
    }
    -(nn[0] * ray[0] + nn[1] * ray[1] + nn[2] * ray[2]) / (nl * l)
}
