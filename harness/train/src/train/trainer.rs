//! The trainer: the loop and the schedule. It owns the training views, the
//! view order, the iteration count and the stage schedule, and drives one
//! model per stage. Each stage lives in its folder under `stages/`: its
//! model, settings, checkpoint part, outputs, and `stage.rs`, the
//! transition from the previous stage and one iteration as this trainer
//! calls it (`impl Trainer` blocks there). This file holds what every
//! stage shares: the views and their order, the cached frozen scattering
//! colour, the dispatch of an iteration to its stage, and the render.
//! Models never refer to the trainer: each step gets what it needs as
//! arguments.

use super::config::TrainConfig;
use tgs_pipelines::Rng;
use super::schedule::{Schedule, Stage};
use super::stages::light_field::LightFieldModel;
use super::stages::reflection::{reflection_decides, ReflDecision, ReflectionModel};
use super::stages::scattering::init::{far_points, gaussians_from_points, random_points};
use super::stages::scattering::ScatteringModel;
use crate::data::Dataset;
use anyhow::{Context as _, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Timing};
use tgs_pipelines::{Camera, HostGaussians, LossValues, Plane};

pub use super::stages::reflection::ReflRendered;
pub use super::stages::scattering::Rendered;

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
    pub(crate) scat_cache: Vec<Buffer<f32>>,
    pub(crate) ctx: Arc<Context>,
    pub(crate) targets: Vec<Buffer<f32>>,
    pub(crate) cameras: Vec<Camera>,
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

    pub(crate) fn next_view(&mut self) -> u32 {
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

    /// The entry of the schedule the next iteration belongs to, and its
    /// name ("II", "II.2", ...).
    pub fn next_entry(&self) -> (usize, String) {
        let i = self.schedule.entry_at(self.iteration + 1).unwrap_or(self.schedule.stages.len().saturating_sub(1));
        (i, self.schedule.label(i))
    }

    /// The frozen scattering colour of every training view (rendered again
    /// after a resume).
    pub(crate) fn ensure_scat_cache(&mut self) -> Result<()> {
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
        match stage {
            Stage::Scattering => self.step_scattering(it, stage, profile),
            Stage::Reflection => self.step_reflection(it, stage_it, profile),
            Stage::LightField => self.step_light_field(it, stage_it, profile),
        }
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
