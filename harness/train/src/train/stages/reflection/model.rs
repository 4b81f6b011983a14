//! Stage II's model (paper §3.3, method-notes §3.4): the reflection set (2DGS
//! geometry + raw f0 and r, a `TrainableSet` whose feature block is that
//! material), the learnable cube map, and what trains them against the
//! frozen Stage I render: per view, the reflection colour per Gaussian, the
//! rasterization of [c, r (, f0)], the deferred composite with the cached
//! scattering colour, L1 + D-SSIM on the composite with normal consistency
//! on the reflection set, the backward through all of it, Adam, and
//! prune-only density control. Never refers to the trainer.

use super::config::ReflectionConfig;
use super::light::{record_forward, CubeMapLight, Pass};
use super::masks::GlassMask;
use super::seed::{quat_for_normal, Seed};
use crate::train::config::TrainConfig;
use crate::train::logit;
use crate::train::stages::composite::{record_composite_step, CompositeLoss, HfSetting, LossTerms, StepBuffers};
use crate::train::stages::rendered::ReflRendered;
use crate::train::stages::scattering::{ExternalStep, ScatteringModel, StepOutput};
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Readback, Recorder, Timing};
use tgs_pipelines::reflection::{ColorInputs, CompositeInputs, TexelScratch, MATERIAL};
use tgs_pipelines::{
    Adam, AdamGroup, Camera, Densifier, DensifyParams, EnvMap, Features, Fresnel, HostEnvMap, HostGaussians, LossWeights, Rasterizer, ReflectionShading, TrainableSet,
};

/// What the trainer passes for one Stage II step.
pub struct ReflStepInput<'a> {
    /// Iteration within Stage II (1-based): the Adam step count.
    pub iteration: u32,
    pub camera: &'a Camera,
    pub target: &'a Buffer<f32>,
    /// The frozen scattering colour of this view (3 planes); None when
    /// the step trains the scattering colour ([`ScatTrain`]).
    pub scat: Option<&'a Buffer<f32>>,
    /// Position learning rate (already scaled by the extent).
    pub lr_means: f32,
    pub profile: bool,
    /// The view's glass mask the set's alpha is drawn to (`reflection.lambda_mask`).
    pub mask: Option<&'a GlassMask>,
}

/// Stage II training the scattering set's SH colour too
/// (`reflection.train_scattering`): its geometry, opacity and their Adam
/// moments stay as Stage I left them.
pub struct ScatTrain<'a> {
    pub model: &'a mut ScatteringModel,
    /// Stage I's final SH degree.
    pub sh_degree: u32,
    pub background: [f32; 3],
    /// The global iteration: the scattering set's Adam step count.
    pub global_iteration: u32,
}

struct ViewBuffers {
    step: StepBuffers,
    /// The alpha plane, brought back with the step when `lambda_area` > 0.
    alpha_host: Readback<f32>,
}

pub struct ReflectionModel {
    ctx: Arc<Context>,
    raster: Rasterizer,
    shading: ReflectionShading,
    objective: CompositeLoss,
    adam: Adam,
    densifier: Densifier,
    pub fresnel: Fresnel,
    pub set: TrainableSet,
    pub env: EnvMap,
    /// Rasterized features and their gradients (channels per Gaussian).
    feat: Buffer<f32>,
    dfeat: Buffer<f32>,
    texels: TexelScratch,
    sizes: HashMap<(u32, u32), ViewBuffers>,
    /// Per training view, its glass mask when `reflection.lambda_mask` draws the set to it.
    pub masks: Vec<Option<GlassMask>>,
}

impl ReflectionModel {
    /// A reflection set with the geometry of the scattering Gaussians `copy`
    /// (when given) followed by the residual-hull `seeds` (opacity
    /// `seed_opacity`), f0 and r at their initial values, and the cube map
    /// `env`.
    pub fn from_scattering(ctx: &Arc<Context>, copy: Option<&HostGaussians>, seeds: &[Seed], env: HostEnvMap, rc: &ReflectionConfig, adam_eps: f32) -> Result<ReflectionModel> {
        let mut h = HostGaussians::new(MATERIAL, 1);
        let (f0, r) = (logit(rc.f0_init), logit(rc.r_init));
        if let Some(scat) = copy {
            for i in 0..scat.len() {
                let g = |v: &[f32], w: usize| -> Vec<f32> { v[w * i..w * (i + 1)].to_vec() };
                h.push(g(&scat.means, 3).try_into().unwrap(), g(&scat.log_scales, 2).try_into().unwrap(), g(&scat.quats, 4).try_into().unwrap(), scat.opacity[i], &[f0, f0, f0, r]);
            }
        }
        for s in seeds {
            let ls = s.scale.ln();
            h.push(s.position, [ls, ls], quat_for_normal(s.normal), logit(rc.seed_opacity), &[f0, f0, f0, r]);
        }
        if h.is_empty() {
            bail!("the reflection set would be empty (reflection.init = '{}' found nothing to start from)", rc.init);
        }
        Self::new(ctx, &h, &env, rc.fresnel.pipeline(), adam_eps)
    }

    pub fn new(ctx: &Arc<Context>, set: &HostGaussians, env: &HostEnvMap, fresnel: Fresnel, adam_eps: f32) -> Result<ReflectionModel> {
        if set.channels != MATERIAL || set.coeffs != 1 {
            bail!("a reflection set has {MATERIAL} material values per Gaussian, not {} x {}", set.channels, set.coeffs);
        }
        let shading = ReflectionShading::new(ctx)?;
        let env = EnvMap::upload(ctx, env)?;
        let n = set.len().max(1);
        let ch = fresnel.channels() as usize;
        Ok(ReflectionModel {
            raster: Rasterizer::new(ctx, fresnel.channels(), Features::Plain)?,
            objective: CompositeLoss::new(ctx)?,
            adam: Adam::new(ctx, adam_eps)?,
            densifier: Densifier::new(ctx)?,
            texels: shading.texel_scratch(&env, n as u32)?,
            shading,
            fresnel,
            set: TrainableSet::new(ctx, set)?,
            env,
            // The colour kernel writes every Gaussian's features before the
            // rasterizer reads them; the rasterizer's reduce writes the gradients.
            feat: Buffer::uninit(ctx, "refl.features", ch * n)?,
            dfeat: Buffer::uninit(ctx, "refl.d_features", ch * n)?,
            sizes: HashMap::new(),
            masks: Vec::new(),
            ctx: ctx.clone(),
        })
    }

    fn view_buffers(&mut self, w: u32, h: u32) -> Result<()> {
        let n = self.set.len();
        let old = self.sizes.get(&(w, h)).map(|b| (b.step.frame.max_gaussians, b.step.frame.capacity));
        if old.is_none_or(|(max_g, _)| max_g < n) {
            let max_g = n + 1024;
            let cap = old.map(|o| o.1).unwrap_or(0).max(self.raster.initial_capacity(max_g));
            let frame = self.raster.frame(w, h, max_g, cap)?;
            let vb = ViewBuffers { step: StepBuffers::new(&self.ctx, &self.objective, frame, "refl")?, alpha_host: Readback::new(&self.ctx, "refl.alpha_host", (w * h) as usize)? };
            self.sizes.insert((w, h), vb);
        }
        Ok(())
    }

    /// Colour + rasterization of `cam`, re-run until the frame fits.
    fn forward(&mut self, cam: &Camera, profile: bool) -> Result<Vec<Timing>> {
        self.view_buffers(cam.width, cam.height)?;
        let b = self.sizes.get_mut(&(cam.width, cam.height)).context("reflection view buffers")?;
        loop {
            let mut rec = Recorder::profiled_if(&self.ctx, profile)?;
            record_forward(&mut rec, (&self.shading, &self.raster), &ColorInputs { g: &self.set.params, env: &self.env, cam, fresnel: self.fresnel }, &self.feat, &b.step.frame)?;
            let t = rec.submit_and_wait()?;
            if self.raster.fit(&mut b.step.frame)? {
                return Ok(t);
            }
        }
    }

    /// One Stage II step on one view, in one submission: colour,
    /// rasterization, composite, loss, the backward through all of it and
    /// Adam on the set and the environment map, the updates gated on the GPU
    /// by whether the view fitted its frame (when it did not, nothing was
    /// updated, the frame grows and the step runs again). Prunes when the
    /// schedule says so (its own submissions).
    ///
    /// With `train` the scattering set's colour trains too: its forward and
    /// this set's run first (their own submissions, so that the step's
    /// submission fits its frame at once: the scattering set's Adam step in
    /// it is not gated), and the composite's gradient to the scattering
    /// colour flows back through its rasterizer to its SH coefficients.
    pub fn step(&mut self, cfg: &TrainConfig, x: &ReflStepInput, train: Option<ScatTrain>) -> Result<StepOutput> {
        let rc = &cfg.reflection;
        // The mask loss acts only with a weight: the mask is dropped here once for the whole step.
        let x = &ReflStepInput { mask: x.mask.filter(|_| rc.lambda_mask > 0.0), ..*x };
        let cam = x.camera;
        let mut pre = Vec::new();
        // The trained scattering model, its SH degree and Adam step count.
        let scat_model: Option<(&ScatteringModel, u32, u32)> = match train {
            Some(t) => {
                pre.extend(t.model.forward_view(cam, t.sh_degree, &t.background, x.profile)?);
                pre.extend(self.forward(cam, x.profile)?);
                Some((&*t.model, t.sh_degree, t.global_iteration))
            }
            None => None,
        };
        let (scat, scat_grad) = match scat_model {
            Some((m, ..)) => {
                let (out, grad) = m.frame_buffers(cam.width, cam.height)?;
                (out, Some(grad))
            }
            None => (x.scat.context("a frozen Stage II step needs the scattering colour")?, None),
        };
        let weights = LossWeights { ssim: cfg.lambda_ssim, normal: rc.lambda_normal, dist: 0.0 };
        let groups = [
            AdamGroup::single(x.lr_means),
            AdamGroup::single(rc.lr_scales),
            AdamGroup::single(rc.lr_quats),
            AdamGroup::single(rc.lr_opacity),
            // Material: f0 (3) at lr_f0, r at lr_r.
            AdamGroup::split(rc.lr_f0, rc.lr_r, MATERIAL, 3),
        ];
        let it = x.iteration as u64;
        let external = scat_model.map(|(m, sh_degree, iteration)| (m, ExternalStep { sh_degree, lr_means: x.lr_means, iteration, colour_only: true }));
        let hf = HfSetting { lambda: rc.lambda_hf, percentile: rc.hf_percentile };
        let pass = Pass { scat, terms: LossTerms { weights, hf, scat_grad }, external, groups, it };
        let (timings, values) = loop {
            self.view_buffers(cam.width, cam.height)?;
            let mut rec = Recorder::profiled_if(&self.ctx, x.profile)?;
            self.record_pass(&mut rec, cfg, x, &pass)?;
            let t = rec.submit_and_wait()?;
            let b = self.sizes.get_mut(&(cam.width, cam.height)).context("reflection view buffers")?;
            if self.raster.fit(&mut b.step.frame)? {
                break (t, b.step.loss.values()?);
            }
            if scat_model.is_some() {
                bail!("a Stage II step that trains the scattering colour overflowed the frame its own forward had just fitted");
            }
        };
        let timings = pre.into_iter().chain(timings).collect();
        let mut loss = self.objective.value(&values, cfg.lambda_ssim, &weights, hf)?;
        if rc.lambda_r > 0.0 {
            loss += rc.lambda_r as f64 * crate::train::mean(&self.sizes[&(cam.width, cam.height)].step.r_host.read()?);
        }
        if rc.lambda_area > 0.0 || x.mask.is_some() {
            let alpha = self.sizes[&(cam.width, cam.height)].alpha_host.read()?;
            loss += rc.lambda_area as f64 * crate::train::mean(&alpha);
            if let Some(m) = x.mask {
                let sq: f64 = alpha.iter().zip(&m.host).map(|(&a, &g)| (a as f64 - g as u8 as f64).powi(2)).sum();
                loss += 0.5 * rc.lambda_mask as f64 * sq / alpha.len().max(1) as f64;
            }
        }

        let mut densified = None;
        if rc.prune_interval > 0 && x.iteration.is_multiple_of(rc.prune_interval) && x.iteration > 0 {
            let r = self.densifier.densify(&mut self.set, &prune_below(cfg.prune_opacity))?;
            densified = Some((r.before, r.after));
        }
        Ok(StepOutput { loss, values, densified, timings })
    }

    /// One recording of a Stage II step (see [`Self::step`]): the shared
    /// composite step around the cube map's [`CubeMapLight`].
    fn record_pass(&mut self, rec: &mut Recorder, cfg: &TrainConfig, x: &ReflStepInput, p: &Pass<'_>) -> Result<()> {
        let cam = x.camera;
        let ReflectionModel { raster, shading, objective, adam, fresnel, set, env, feat, dfeat, texels, sizes, .. } = self;
        let ViewBuffers { step, alpha_host } = sizes.get_mut(&(cam.width, cam.height)).context("reflection view buffers")?;
        let (step, io) = step.split(objective, x.target, cam, p.terms, (feat, dfeat));
        let mut light = CubeMapLight { cfg, cam, p, raster, shading, adam, fresnel: *fresnel, set, env, io, texels, alpha_host, mask: x.mask };
        record_composite_step(rec, &mut light, step)
    }

    /// Render `cam` composited over the scattering colour `scat` (3 planes).
    pub fn render(&mut self, cam: &Camera, scat: &Buffer<f32>) -> Result<ReflRendered> {
        self.forward(cam, false)?;
        let b = &self.sizes[&(cam.width, cam.height)].step;
        let mut rec = Recorder::new(&self.ctx)?;
        self.shading.record_composite(&mut rec, cam, self.fresnel, &CompositeInputs { scat, refl: &b.frame.out }, &b.loss_in)?;
        rec.submit_and_wait()?;
        Ok(ReflRendered { width: cam.width, height: cam.height, composite: b.loss_in.download()?, refl: b.frame.out.download()?, channels: self.fresnel.channels(), phi: None })
    }
}

/// Density control that only prunes: the Gaussians whose opacity is under `opacity_min`.
fn prune_below(opacity_min: f32) -> DensifyParams {
    DensifyParams { grad_threshold: f32::INFINITY, dense_scale: 0.0, opacity_min, prune_big: false, big_screen: f32::INFINITY, big_world: f32::INFINITY, grow: false, seed: 0 }
}

/// A raw opacity no Gaussian renders with (sigmoid 0 in f32).
const DEAD: f32 = -200.0;

/// `opacity` with the Gaussians `marked` set to [`DEAD`].
fn dead_where(opacity: &[f32], marked: &[bool]) -> Vec<f32> {
    opacity.iter().zip(marked).map(|(&o, &m)| if m { DEAD } else { o }).collect()
}

impl ReflectionModel {
    /// The set's raw opacities, for [`Self::render_without`].
    pub fn opacities(&self) -> Result<Vec<f32>> {
        self.set.params.opacity.download()
    }

    /// Render `cam` over `scat` as [`Self::render`] with the Gaussians
    /// `hidden` marks left out (`opacity` is the set's own, put back after).
    pub fn render_without(&mut self, cam: &Camera, scat: &Buffer<f32>, opacity: &[f32], hidden: &[bool]) -> Result<ReflRendered> {
        self.set.params.opacity.upload(&dead_where(opacity, hidden))?;
        let r = self.render(cam, scat);
        self.set.params.opacity.upload(opacity)?;
        r
    }

    /// Remove the Gaussians `drop` marks (with their Adam moments): the
    /// number before and after.
    pub fn remove(&mut self, drop: &[bool]) -> Result<(u32, u32)> {
        self.set.params.opacity.upload(&dead_where(&self.opacities()?, drop))?;
        // Only what renders nothing at all goes.
        let r = self.densifier.densify(&mut self.set, &prune_below(f32::MIN_POSITIVE))?;
        Ok((r.before, r.after))
    }

    /// The reflection set (Stage III keeps it, with its Adam moments).
    pub fn into_set(self) -> TrainableSet {
        self.set
    }
}

/// The Stage I residual of one view: 4 planes (r (3), mean_c |r_c|).
pub fn residual(ctx: &Arc<Context>, shading: &ReflectionShading, target: &Buffer<f32>, scat: &Buffer<f32>, pixels: u32) -> Result<Vec<f32>> {
    let out = Buffer::<f32>::new(ctx, "refl.residual", 4 * pixels as usize)?;
    let mut rec = Recorder::new(ctx)?;
    shading.record_residual(&mut rec, pixels, target, scat, &out)?;
    rec.submit_and_wait()?;
    out.download()
}
