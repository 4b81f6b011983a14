//! The trainer: the loop and the schedule. It owns the training views, the
//! view order, the iteration count and the stage schedule, and drives one
//! model per stage (`scattering::ScatteringModel` for Stage I,
//! `reflection::ReflectionModel` for Stage II, `lightfield::LightFieldModel`
//! for Stage III).
//! Between the stages it computes the Stage I residual, decides whether
//! the scene calls for Stage II, and caches the frozen scattering colour of
//! every training view. Models never refer to the trainer: each step gets
//! what it needs as arguments.

use super::config::TrainConfig;
use super::init::{far_points, gaussians_from_points, random_points};
use super::lightfield::{normalization_box, LightFieldModel, LightFieldStepInput};
use super::env_init::{scene_env_map, EnvInit};
use super::rng::Rng;
use super::reflection::{residual, ReflStepInput, ReflectionModel, ScatTrain};
use super::scattering::{ScatteringModel, StepInput};
use super::seed::{hull_seeding, SeedParams, SeedView};
use super::view_dependence::{view_dependence, VdMap};
use crate::data::Dataset;
use anyhow::{Context as _, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Timing};
use tgs_pipelines::{Camera, EnvProxy, HostEnvMap, HostGaussians, LossValues, Plane, ReflectionShading};

pub use super::reflection::ReflRendered;
pub use super::scattering::Rendered;

/// Training stages (paper §3–4).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Stage {
    /// Stage I: the scattering set alone (2DGS).
    #[default]
    Scattering,
    /// Stage II: reflection set + environment map over the frozen Stage I set.
    Reflection,
    /// Stage III: the reflection light field MLP (reflection geometry frozen).
    LightField,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Scattering => "I",
            Stage::Reflection => "II",
            Stage::LightField => "III",
        }
    }
}

/// The view-dependence measure reduces each view to at most this many
/// pixels a side (box-averaged: Monte Carlo noise in the images, which
/// also spreads the residual across views, is then about as strong at any
/// image size) and samples at most this many pixels in all.
const VD_MAX_SIDE: u32 = 64;
const VD_SAMPLES: usize = 1 << 16;

/// The measured Stage I residual and what it decided (metrics.json's `reflection`).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ReflDecision {
    /// Mean over the training views of the per-pixel mean_c |I_gt - I_scat|.
    pub residual_mean: f64,
    /// Fraction of training pixels whose residual magnitude exceeds 0.05.
    pub residual_fraction_over_0_05: f64,
    /// The threshold on `residual_mean` (reflection.min_residual).
    pub threshold: f64,
    /// How much the residual changes with the view at a fixed Stage I
    /// surface point (train/view_dependence.rs), over how many samples,
    /// and its threshold (reflection.min_view_dependence).
    #[serde(default)]
    pub view_dependence: f64,
    #[serde(default)]
    pub view_dependence_samples: u64,
    #[serde(default)]
    pub view_dependence_threshold: f64,
    /// Whether Stage II ran.
    pub run: bool,
    /// 1, or 2 for the Stage II run again after Stage III (reflection.reseed).
    #[serde(default)]
    pub round: u32,
    pub reflection_gaussians: u32,
    /// Of those: residual-hull seeds, and Stage I Gaussians copied.
    #[serde(default)]
    pub seeds: u32,
    #[serde(default)]
    pub copied: u32,
    /// The residual hull gave no seed, so the set started as a copy of
    /// Stage I's (reflection.init = "hull").
    #[serde(default)]
    pub hull_empty: bool,
    /// No hull point beat chance at reflection.seed_significance (too few
    /// views, or residual over most of every image), so the seeds come
    /// from the hull without that test.
    #[serde(default)]
    pub significance_dropped: bool,
    /// The cube map started from the scene (reflection.env_init = "scene"):
    /// the box it was rendered from and the Gaussians outside it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub env_from: Option<EnvInit>,
    /// The cube map's parallax proxy (reflection.env_radius > 0, or the
    /// centre of a map with depth, env_init = "scene-depth"): centre and
    /// radius in world units, fixed when Stage II starts.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub env_proxy: Option<[f32; 4]>,
}

/// The stage schedule: each stage with its iteration count, run in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Schedule {
    pub stages: Vec<(Stage, u32)>,
}

impl Schedule {
    pub fn from_config(cfg: &TrainConfig) -> Schedule {
        let mut stages = vec![(Stage::Scattering, cfg.iterations)];
        if cfg.wants_reflection() {
            stages.push((Stage::Reflection, cfg.reflection.iterations));
        }
        if cfg.wants_light_field() {
            stages.push((Stage::LightField, cfg.light_field.iterations));
            if cfg.reflection.reseed {
                stages.push((Stage::Reflection, cfg.reflection.iterations));
                stages.push((Stage::LightField, cfg.light_field.iterations));
            }
        }
        Schedule { stages }
    }
    /// The index in `stages` of global iteration `it` (1-based).
    pub fn entry_at(&self, it: u32) -> Option<usize> {
        let mut start = 0;
        for (i, &(_, n)) in self.stages.iter().enumerate() {
            if it > start && it <= start + n {
                return Some(i);
            }
            start += n;
        }
        None
    }
    /// Entry `i`'s round: 1, or 2 for a stage run again (reflection.reseed).
    pub fn round(&self, i: usize) -> u32 {
        let s = self.stages.get(i).map(|e| e.0);
        1 + self.stages[..i.min(self.stages.len())].iter().filter(|e| Some(e.0) == s).count() as u32
    }
    /// Entry `i`'s name in logs and metrics: "II", or "II.2" in round 2.
    pub fn label(&self, i: usize) -> String {
        let name = self.stages.get(i).map(|e| e.0.name()).unwrap_or("?");
        match self.round(i) {
            1 => name.to_string(),
            r => format!("{name}.{r}"),
        }
    }
    /// The iterations of the entry named `label`.
    pub fn iterations_of(&self, label: &str) -> u32 {
        (0..self.stages.len()).find(|&i| self.label(i) == label).map(|i| self.stages[i].1).unwrap_or(0)
    }
    /// First global iteration of `stage` minus one (its iterations are start+1..).
    pub fn start_of(&self, stage: Stage) -> u32 {
        self.stages.iter().take_while(|s| s.0 != stage).map(|s| s.1).sum()
    }
    /// Drop the stages after `stage` (a skipped Stage II).
    pub fn end_after(&mut self, stage: Stage) {
        if let Some(i) = self.stages.iter().position(|s| s.0 == stage) {
            self.stages.truncate(i + 1);
        }
    }
    pub fn total(&self) -> u32 {
        self.stages.iter().map(|s| s.1).sum()
    }
    /// The stage of global iteration `it` (1-based) and the iteration within it.
    pub fn at(&self, it: u32) -> Option<(Stage, u32)> {
        let i = self.entry_at(it)?;
        let start: u32 = self.stages[..i].iter().map(|e| e.1).sum();
        Some((self.stages[i].0, it - start))
    }
}

/// What one iteration did.
#[derive(Clone, Debug, Default)]
pub struct StepReport {
    pub iteration: u32,
    pub stage: Stage,
    pub view: u32,
    pub loss: f64,
    pub values: LossValues,
    pub gaussians: u32,
    pub densified: Option<(u32, u32)>,
    /// The opacity reset (after the previous iteration) ran before this one.
    pub opacity_reset: bool,
    pub timings: Vec<Timing>,
}

pub struct Trainer {
    pub cfg: TrainConfig,
    pub schedule: Schedule,
    /// Stage I's model: the scattering set.
    pub scattering: ScatteringModel,
    /// Stage II's model, from the start of Stage II to the start of Stage III.
    pub reflection: Option<ReflectionModel>,
    /// Stage III's model, from the start of Stage III.
    pub light_field: Option<LightFieldModel>,
    /// The Stage I residual's measurement and the Stage II decision.
    pub decision: Option<ReflDecision>,
    /// The frozen scattering colour of every training view (Stage II).
    scat_cache: Vec<Buffer<f32>>,
    ctx: Arc<Context>,
    targets: Vec<Buffer<f32>>,
    cameras: Vec<Camera>,
    /// Completed iterations.
    pub iteration: u32,
    pub rng: Rng,
    /// Training views not yet used in this pass (popped from the back).
    pub stack: Vec<u32>,
    pub extent: f32,
    /// The training cameras' mean: with `extent`, the camera sphere.
    pub centre: [f32; 3],
    pub background: [f32; 3],
}

impl Trainer {
    /// A trainer with Gaussians initialised from the dataset's points (or
    /// random points when it has none).
    pub fn new(ctx: &Arc<Context>, cfg: TrainConfig, data: &Dataset) -> Result<Trainer> {
        let mut rng = Rng::new(cfg.seed);
        let points = match &data.points {
            Some(p) if !p.positions.is_empty() => p.clone(),
            _ => {
                let mut p = random_points(cfg.init_points, cfg.init_half_extent, &mut rng);
                let cams: Vec<Camera> = data.train.iter().map(|v| v.camera).collect();
                let (extent, centre) = data.extent();
                let n = (cfg.init_far_fraction as f64 * cfg.init_points as f64).round() as u32;
                let far = far_points(n, &cams, cfg.init_half_extent, (centre, extent), cfg.init_far_depth * extent, &mut rng);
                p.positions.extend(far.positions);
                p.colors.extend(far.colors);
                p
            }
        };
        let g = gaussians_from_points(&points, cfg.sh_degree, &mut rng);
        Self::with_gaussians(ctx, cfg, data, &g, rng)
    }

    pub fn with_gaussians(ctx: &Arc<Context>, cfg: TrainConfig, data: &Dataset, g: &HostGaussians, rng: Rng) -> Result<Trainer> {
        cfg.validate()?;
        let targets = data.train.iter().map(|v| Buffer::from_slice(ctx, "train.target", &v.image.planar())).collect::<Result<Vec<_>>>()?;
        let cameras = data.train.iter().map(|v| v.camera).collect();
        let (extent, centre) = data.extent();
        Ok(Trainer {
            schedule: Schedule::from_config(&cfg),
            scattering: ScatteringModel::new(ctx, g, cfg.sh_degree, cfg.adam_eps)?,
            reflection: None,
            light_field: None,
            decision: None,
            scat_cache: Vec::new(),
            ctx: ctx.clone(),
            targets,
            cameras,
            iteration: 0,
            rng,
            stack: Vec::new(),
            extent,
            centre,
            background: data.background,
            cfg,
        })
    }

    /// The device context the models run on.
    pub fn context(&self) -> Arc<Context> {
        self.ctx.clone()
    }

    pub fn done(&self) -> bool {
        self.iteration >= self.schedule.total()
    }

    /// Active SH degree at iteration `it` (one more every `sh_interval`).
    pub fn sh_degree(&self, it: u32) -> u32 {
        self.cfg.sh_degree_at(it)
    }

    /// Position learning rate at iteration `it`: log-linear over the stage, x extent.
    pub fn lr_means(&self, it: u32) -> f32 {
        (super::log_lerp(self.cfg.lr_means, self.cfg.lr_means_final, it as f64 / self.cfg.iterations.max(1) as f64) * self.extent as f64) as f32
    }

    fn next_view(&mut self) -> u32 {
        if self.stack.is_empty() {
            let n = self.cameras.len() as u32;
            self.stack = (0..n).collect();
            for i in (1..self.stack.len()).rev() {
                let j = self.rng.below(i as u64 + 1) as usize;
                self.stack.swap(i, j);
            }
        }
        self.stack.pop().unwrap_or(0)
    }

    /// Whether the next iteration starts Stage II (call
    /// [`Trainer::begin_reflection`] first).
    pub fn at_reflection_start(&self) -> bool {
        // A Stage II run again after Stage III starts while the light
        // field is still there.
        (self.scat_cache.is_empty() || self.light_field.is_some()) && matches!(self.schedule.at(self.iteration + 1), Some((Stage::Reflection, _)))
    }

    /// The entry of the schedule the next iteration belongs to, and its
    /// name ("II", "II.2", ...).
    pub fn next_entry(&self) -> (usize, String) {
        let i = self.schedule.entry_at(self.iteration + 1).unwrap_or(self.schedule.stages.len().saturating_sub(1));
        (i, self.schedule.label(i))
    }

    /// Between Stage I and II: render every training view with the frozen
    /// scattering set (cached for Stage II), measure the residual
    /// I_gt - I_scat on the GPU, and decide: below `reflection.min_residual`
    /// the scene shows no view-dependent energy worth a reflection set and
    /// the schedule ends after Stage I. `on_view(i, residual planes)` sees
    /// every view's residual (4 planes: r, mean |r|) for saving.
    pub fn begin_reflection(&mut self, mut on_view: impl FnMut(usize, &Camera, &[f32]) -> Result<()>) -> Result<ReflDecision> {
        let shading = ReflectionShading::new(&self.ctx)?;
        let sh = self.sh_degree(self.cfg.iterations);
        let (mut sum, mut over, mut pixels) = (0.0f64, 0usize, 0usize);
        // Stage II again (reflection.reseed): the light field and its
        // reflection set give way to a set seeded afresh.
        let reseed = self.light_field.take().is_some();
        let round = self.schedule.round(self.next_entry().0);
        self.scat_cache.clear();
        // Per view: residual magnitude and Stage I surface depth (seeding),
        // and both reduced for the view-dependence measure.
        let mut maps: Vec<(Vec<f32>, Vec<f32>)> = Vec::new();
        let mut vd_maps: Vec<VdMap> = Vec::new();
        let (copy, hull) = self.cfg.reflection.init.parts();
        for (i, cam) in self.cameras.clone().iter().enumerate() {
            let n = (cam.width * cam.height) as usize;
            let buf = Buffer::<f32>::new(&self.ctx, "train.scat_cache", 3 * n)?;
            self.scattering.render_color_into(cam, sh, &self.background, &buf)?;
            let r = residual(&self.ctx, &shading, &self.targets[i], &buf, n as u32)?;
            let mag = &r[3 * n..4 * n];
            sum += mag.iter().map(|&v| v as f64).sum::<f64>() / n as f64;
            over += mag.iter().filter(|&&v| v > 0.05).count();
            pixels += n;
            on_view(i, cam, &r)?;
            self.scat_cache.push(buf);
            // The frame still holds this view's render.
            let depth = self.scattering.last_plane(cam.width, cam.height, Plane::Median)?;
            vd_maps.push(VdMap::new(cam, &r, &depth, VD_MAX_SIDE));
            if hull && self.reflection.is_none() {
                maps.push((mag.to_vec(), depth));
            }
        }
        // A resumed Stage II (its set exists) keeps the decision and seed
        // counts it was started with; only the cache was needed.
        if let (Some(kept), true) = (&self.decision, self.reflection.is_some()) {
            return Ok(kept.clone());
        }
        let views = self.cameras.len().max(1);
        let vd = view_dependence(&vd_maps, (self.centre, self.extent), VD_SAMPLES);
        drop(vd_maps);
        let mut d = ReflDecision {
            residual_mean: sum / views as f64,
            residual_fraction_over_0_05: over as f64 / pixels.max(1) as f64,
            threshold: self.cfg.reflection.min_residual as f64,
            view_dependence: vd.spread,
            view_dependence_samples: vd.samples,
            view_dependence_threshold: self.cfg.reflection.min_view_dependence as f64,
            run: false,
            reflection_gaussians: 0,
            seeds: 0,
            copied: 0,
            hull_empty: false,
            significance_dropped: false,
            env_from: None,
            env_proxy: None,
            round,
        };
        // A reflection set that exists (a resumed Stage II without a
        // recorded decision) was decided on when it was made, and the
        // second round (reflection.reseed) runs whatever its residual: the
        // first decided.
        d.run = reseed || self.reflection.is_some() || (d.residual_mean >= d.threshold && d.view_dependence >= d.view_dependence_threshold);
        if d.run {
            if self.reflection.is_none() {
                let rc = &self.cfg.reflection;
                let views: Vec<SeedView> = self.cameras.iter().zip(&maps).map(|(c, (r, z))| SeedView { camera: *c, residual: r, depth: z }).collect();
                let p = SeedParams { threshold: rc.min_residual, agree: rc.seed_agree, max_rays: rc.seed_rays, normal: rc.seed_normal, significance: rc.seed_significance as f64, ..SeedParams::default() };
                let seeds = if hull {
                    let h = hull_seeding(&views, &p);
                    d.significance_dropped = h.significance_dropped;
                    h.seeds
                } else {
                    Vec::new()
                };
                // No ray crossed carved space into the hull (e.g. a Stage I
                // too short to carve anything): the paper's initialisation,
                // a copy of the Stage I set, rather than no Stage II.
                d.hull_empty = hull && seeds.is_empty();
                let g = if copy || d.hull_empty { Some(self.scattering.set.params.download()?) } else { None };
                d.seeds = seeds.len() as u32;
                d.copied = g.as_ref().map(|g| g.len() as u32).unwrap_or(0);
                let mut means: Vec<f32> = g.as_ref().map(|g| g.means.clone()).unwrap_or_default();
                means.extend(seeds.iter().flat_map(|s| s.position));
                use super::settings::EnvStart;
                let mut env = if matches!(rc.env_init, EnvStart::Scene | EnvStart::SceneDepth) {
                    let scat = self.scattering.set.params.download()?;
                    let depth = rc.env_init == EnvStart::SceneDepth;
                    let (env, info) = scene_env_map(&self.ctx, &scat, sh, &self.background, &means, rc.env_res, self.cfg.adam_eps, depth)?;
                    d.env_from = Some(info);
                    // The depth map's proxy: at the centre it was rendered from.
                    d.env_proxy = env.proxy.map(|p| EnvProxy::packed(Some(p)));
                    env
                } else {
                    HostEnvMap::constant(rc.env_res, 0.0)?
                };
                if rc.env_radius > 0.0 {
                    let p = env_proxy(&means, &self.cameras, rc.env_radius);
                    d.env_proxy = p.map(|p| EnvProxy::packed(Some(p)));
                    env.proxy = p;
                }
                self.reflection = Some(ReflectionModel::from_scattering(&self.ctx, g.as_ref(), &seeds, env, rc, self.cfg.adam_eps)?);
            }
            d.reflection_gaussians = self.reflection.as_ref().map(|r| r.set.len()).unwrap_or(0);
        } else {
            self.schedule.end_after(Stage::Scattering);
            self.scat_cache.clear();
        }
        self.decision = Some(d.clone());
        Ok(d)
    }

    /// Whether the next iteration starts Stage III (call
    /// [`Trainer::begin_light_field`] first).
    pub fn at_light_field_start(&self) -> bool {
        self.light_field.is_none() && matches!(self.schedule.at(self.iteration + 1), Some((Stage::LightField, _)))
    }

    /// Between Stage II and III: the reflection set (with its Adam moments)
    /// moves to a light-field model with a fresh network; the environment
    /// map is dropped. Positions are normalized by the reflection set's box.
    pub fn begin_light_field(&mut self) -> Result<()> {
        let refl = self.reflection.take().context("Stage III starts from Stage II's reflection set, and there is none")?;
        let set = refl.into_set();
        let (centre, half_extent) = normalization_box(&set.params.means.download()?);
        let lf = &self.cfg.light_field;
        let shade = tgs_pipelines::ShadeParams { centre, half_extent, threshold: lf.threshold, schlick: lf.schlick() };
        let net = LightFieldModel::init_net(&self.ctx, lf.shape()?, self.cfg.seed ^ 0x4c46)?;
        self.light_field = Some(LightFieldModel::new(&self.ctx, set, net, shade, self.cfg.adam_eps)?);
        // Stage III renders the scattering colour itself, or caches it
        // again when Stage II changed it.
        if lf.train_scattering || self.cfg.reflection.train_scattering {
            self.scat_cache.clear();
        }
        Ok(())
    }

    /// The frozen scattering colour of every training view (rendered again
    /// after a resume).
    fn ensure_scat_cache(&mut self) -> Result<()> {
        if self.scat_cache.len() == self.cameras.len() {
            return Ok(());
        }
        self.scat_cache.clear();
        let sh = self.sh_degree(self.cfg.iterations);
        for cam in self.cameras.clone() {
            let buf = Buffer::<f32>::new(&self.ctx, "train.scat_cache", 3 * (cam.width * cam.height) as usize)?;
            self.scattering.render_color_into(&cam, sh, &self.background, &buf)?;
            self.scat_cache.push(buf);
        }
        Ok(())
    }

    /// One training iteration.
    pub fn step(&mut self, profile: bool) -> Result<StepReport> {
        let it = self.iteration + 1;
        let (stage, stage_it) = self.schedule.at(it).context("training is already complete")?;
        if stage == Stage::Reflection {
            return self.step_reflection(it, stage_it, profile);
        }
        if stage == Stage::LightField {
            return self.step_light_field(it, stage_it, profile);
        }
        // The reset that follows iteration it-1 runs here, at the start of
        // the next iteration (the same order of operations as 2DGS), so that
        // a test evaluation or checkpoint at it-1 sees the trained state.
        let reset = self.cfg.opacity_reset_after(it - 1, self.background == [1.0; 3]);
        if reset {
            self.scattering.reset_opacity()?;
        }
        let view = self.next_view();
        let cam = self.cameras[view as usize];
        let input = StepInput {
            iteration: it,
            camera: &cam,
            target: &self.targets[view as usize],
            sh_degree: self.sh_degree(it),
            lr_means: self.lr_means(it),
            background: self.background,
            extent: self.extent,
            profile,
        };
        let out = self.scattering.step(&self.cfg, &input)?;
        self.iteration = it;
        Ok(StepReport {
            iteration: it,
            stage,
            view,
            loss: out.loss,
            values: out.values,
            gaussians: self.scattering.set.len(),
            densified: out.densified,
            opacity_reset: reset,
            timings: out.timings,
        })
    }

    fn step_reflection(&mut self, it: u32, stage_it: u32, profile: bool) -> Result<StepReport> {
        let view = self.next_view();
        let cam = self.cameras[view as usize];
        let model = self.reflection.as_mut().context("Stage II has not begun (Trainer::begin_reflection)")?;
        let train = self.cfg.reflection.train_scattering;
        let scat = if train { None } else { Some(self.scat_cache.get(view as usize).context("the scattering colour cache is missing")?) };
        let sh_degree = self.cfg.sh_degree_at(self.cfg.iterations);
        let scat_train = train.then_some(ScatTrain { model: &mut self.scattering, sh_degree, background: self.background, global_iteration: it });
        let input = ReflStepInput {
            iteration: stage_it,
            camera: &cam,
            target: &self.targets[view as usize],
            scat,
            // The reflection geometry starts converged: positions move at
            // Stage I's final rate (method-notes §3.7).
            lr_means: self.cfg.lr_means_final * self.extent,
            profile,
        };
        let out = model.step(&self.cfg, &input, scat_train)?;
        self.iteration = it;
        Ok(StepReport {
            iteration: it,
            stage: Stage::Reflection,
            view,
            loss: out.loss,
            values: out.values,
            gaussians: model.set.len(),
            densified: out.densified,
            opacity_reset: false,
            timings: out.timings,
        })
    }

    fn step_light_field(&mut self, it: u32, stage_it: u32, profile: bool) -> Result<StepReport> {
        let frozen = !self.cfg.light_field.train_scattering;
        if frozen {
            self.ensure_scat_cache()?;
        }
        let view = self.next_view();
        let cam = self.cameras[view as usize];
        let sh = self.sh_degree(self.cfg.iterations);
        let model = self.light_field.as_mut().context("Stage III has not begun (Trainer::begin_light_field)")?;
        let input = LightFieldStepInput {
            iteration: stage_it,
            global_iteration: it,
            camera: &cam,
            target: &self.targets[view as usize],
            scat: if frozen { Some(&self.scat_cache[view as usize]) } else { None },
            sh_degree: sh,
            background: self.background,
            // Positions at Stage I's final rate (method-notes §3.7).
            lr_means: self.cfg.lr_means_final * self.extent,
            profile,
        };
        let out = model.step(&self.cfg, &mut self.scattering, &input)?;
        self.iteration = it;
        Ok(StepReport {
            iteration: it,
            stage: Stage::LightField,
            view,
            loss: out.loss,
            values: out.values,
            gaussians: model.set.len(),
            densified: None,
            opacity_reset: false,
            timings: out.timings,
        })
    }

    /// Render `cam` with the current model: in Stages II and III the composite, with
    /// the geometry planes of the reflection set where it decides a pixel
    /// ([`reflection_decides`]) and of the scattering set elsewhere, and both layers.
    pub fn render(&mut self, cam: &Camera) -> Result<Rendered> {
        let sh = self.sh_degree(self.iteration.min(self.cfg.iterations));
        let scat = self.scattering.render(cam, sh, &self.background)?;
        let n = (cam.width * cam.height) as usize;
        if self.light_field.is_none() && self.reflection.is_none() {
            return Ok(scat);
        }
        let colour = Buffer::from_slice(&self.ctx, "render.scat_colour", &scat.planes[..3 * n])?;
        let refl = match self.light_field.as_mut() {
            Some(model) => model.render(cam, &colour)?,
            None => self.reflection.as_mut().context("a Stage II model")?.render(cam, &colour)?,
        };
        let mut planes = scat.planes.clone();
        planes[..3 * n].copy_from_slice(&refl.composite[..3 * n]);
        let decides: Vec<usize> = (0..n).filter(|&i| reflection_decides(&refl, i, self.cfg.reflection.normal_min_r)).collect();
        for p in [Plane::Alpha, Plane::Depth, Plane::Normal(0), Plane::Normal(1), Plane::Normal(2), Plane::Median, Plane::Distortion] {
            let k = p.index(3) as usize;
            let src = refl.refl_plane(p);
            for &i in &decides {
                planes[k * n + i] = src[i];
            }
        }
        Ok(Rendered { width: cam.width, height: cam.height, planes, layers: Some(Box::new((scat, refl))) })
    }

    /// Current Gaussians on the host.
    pub fn gaussians(&self) -> Result<HostGaussians> {
        self.scattering.set.params.download()
    }
}

/// Whether the reflection set decides the geometry of pixel `i` of a Stage
/// II/III render: it covers the pixel (alpha >= 0.5) and its reflection
/// weight R there reaches `min_r` (`reflection.normal_min_r`).
pub fn reflection_decides(refl: &ReflRendered, i: usize, min_r: f32) -> bool {
    refl.refl_plane(Plane::Alpha)[i] >= 0.5 && refl.r()[i] >= min_r
}

impl ReflDecision {
    /// The recorded parallax proxy of the cube map.
    pub fn proxy(&self) -> Option<EnvProxy> {
        self.env_proxy.map(|p| EnvProxy { centre: [p[0], p[1], p[2]], radius: p[3] })
    }
}

/// The cube map's parallax proxy for `reflection.env_radius` = `radius`:
/// centred on the box of the reflection set's starting positions `means`
/// (as `env_init = "scene"` renders from), of `radius` x the mean distance
/// from there to the `cameras`. None when nothing sets a positive radius.
pub fn env_proxy(means: &[f32], cameras: &[Camera], radius: f32) -> Option<EnvProxy> {
    if means.is_empty() || cameras.is_empty() {
        return None;
    }
    let (centre, _) = normalization_box(means);
    let dist = cameras.iter().map(|c| {
        let e = c.centre();
        (0..3).map(|k| ((e[k] - centre[k]) as f64).powi(2)).sum::<f64>().sqrt()
    }).sum::<f64>() / cameras.len() as f64;
    let r = (radius as f64 * dist) as f32;
    (r > 0.0 && r.is_finite()).then_some(EnvProxy { centre, radius: r })
}
