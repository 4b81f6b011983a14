//! The trainer: the loop and the schedule. It owns the training views and
//! their order, the iteration count, the stage schedule, Stage I's
//! scattering set (the base every later stage renders over) and the later
//! stage that is running, which it drives through [`LaterStage`] without
//! knowing which it is. Each stage lives in its folder under `stages/`:
//! its model, settings, checkpoint part, outputs, and `stage.rs`, the
//! transition from the previous stage (`begin`) and one iteration. This
//! file calls those in schedule order, picks each iteration's view, keeps
//! the schedule in step with what the stages decide, and renders.

use super::config::TrainConfig;
use super::schedule::{Schedule, Stage};
use super::stages::kind::by_stage;
use super::stages::light_field::LightFieldModel;
use super::stages::reflection::{reflection_decides, NormalGate, ReflDecision, ReflectionModel};
use super::stages::scattering::init::{check_budget, far_points, gaussians_from_points, random_points};
use super::stages::scattering::ScatteringModel;
use super::stages::{scattering, Begun, Iteration, LaterKind, LaterStage, RunPaths, ScatCache, Shared, Transition, Views};
use crate::data::Dataset;
use anyhow::{bail, Context as _, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Timing};
use tgs_pipelines::{Camera, HostGaussians, LossValues, Plane, Rng};

pub use super::stages::rendered::{ReflRendered, Rendered};

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
    /// The running stage after Stage I (Stage II's model from its start to
    /// Stage III's, then Stage III's), None before Stage II.
    pub later: Option<Box<dyn LaterStage>>,
    /// The Stage I residual's measurement and the Stage II decision.
    pub decision: Option<ReflDecision>,
    /// The frozen scattering colour of every training view (Stages II, III).
    pub(crate) cache: ScatCache,
    /// The training views, their targets, the background and the camera sphere.
    pub views: Views,
    /// Completed iterations.
    pub iteration: u32,
    pub rng: Rng,
    /// Training views not yet used in this pass (popped from the back).
    pub stack: Vec<u32>,
    /// The validation views (`validation_every`) have been dropped from
    /// `views`: from the first later stage on.
    pub held_out: bool,
}

impl Trainer {
    /// A trainer with Gaussians initialised from the dataset's points (or
    /// random points when it has none).
    pub fn new(ctx: &Arc<Context>, cfg: TrainConfig, data: &Dataset) -> Result<Trainer> {
        let mut rng = Rng::new(cfg.seed);
        let points = match &data.points {
            Some(p) if !p.positions.is_empty() => {
                check_budget(ctx.caps(), p.positions.len() as u64, cfg.sh_degree, "the dataset's points")?;
                p.clone()
            }
            _ => {
                let n = (cfg.init_far_fraction as f64 * cfg.init_points as f64).round() as u32;
                check_budget(ctx.caps(), cfg.init_points as u64 + n as u64, cfg.sh_degree, "init_points (with init_far_fraction)")?;
                let mut p = random_points(cfg.init_points, cfg.init_half_extent, &mut rng);
                let cams: Vec<Camera> = data.train.iter().map(|v| v.camera).collect();
                let (extent, centre) = data.extent();
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
        let masks = data.train.iter().map(|v| v.mask.clone()).collect();
        let (extent, centre) = data.extent();
        let mut tr = Trainer {
            schedule: Schedule::from_config(&cfg),
            scattering: ScatteringModel::new(ctx, g, cfg.sh_degree, cfg.adam_eps)?,
            later: None,
            decision: None,
            cache: ScatCache::default(),
            views: Views { ctx: ctx.clone(), cameras, targets, background: data.background, masks, extent, centre },
            iteration: 0,
            rng,
            stack: Vec::new(),
            held_out: false,
            cfg,
        };
        if tr.cfg.validation_all_stages {
            tr.hold_out_validation(true);
        }
        Ok(tr)
    }

    /// The device context the models run on.
    pub fn context(&self) -> Arc<Context> {
        self.views.ctx.clone()
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
        scattering::stage::lr_means(&self.cfg, self.views.extent, it)
    }

    /// Stage II's model, while Stage II runs.
    pub fn reflection(&self) -> Option<&ReflectionModel> {
        self.later.as_ref()?.as_any().downcast_ref()
    }

    /// Stage II's model to change, while Stage II runs.
    pub fn reflection_mut(&mut self) -> Option<&mut ReflectionModel> {
        self.later.as_mut()?.as_any_mut()?.downcast_mut()
    }

    /// Stage III's model, while Stage III runs.
    pub fn light_field(&self) -> Option<&LightFieldModel> {
        self.later.as_ref()?.as_any().downcast_ref()
    }

    fn next_view(&mut self) -> u32 {
        if self.stack.is_empty() {
            let n = self.views.cameras.len() as u32;
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

    fn next_stage(&self) -> Option<Stage> {
        self.schedule.at(self.iteration + 1).map(|(s, _)| s)
    }

    /// The later stage the next iteration belongs to, when it has to be
    /// begun first ([`Trainer::begin_next`]): the stage has not started,
    /// or (Stage II) it resumes without its cached scattering colours.
    pub fn next_begins(&self) -> Option<&'static dyn LaterKind> {
        let kind = by_stage(self.next_stage()?)?;
        kind.needs_begin(self.later.as_deref(), self.cache.is_empty()).then_some(kind)
    }

    /// The transition into the stage [`Trainer::next_begins`] names (its
    /// `stage.rs`; Stage II: the residual, the decision, the seeds;
    /// Stage III: the light-field model from Stage II's set). A stage
    /// that decides not to run (a skipped Stage II) ends the schedule
    /// before it. `files`: where the transition may write what it
    /// measured (Stage II's residual maps).
    pub fn begin_next(&mut self, files: Option<RunPaths<'_>>, quiet: bool) -> Result<Begun> {
        let kind = self.next_begins().context("the next iteration begins no stage")?;
        self.hold_out_validation(true);
        let (entry, label) = self.next_entry();
        let round = self.schedule.round(entry);
        let t = Transition {
            shared: Shared { cfg: &self.cfg, views: &self.views, scattering: &mut self.scattering, cache: &mut self.cache },
            previous: self.later.take(),
            decision: &mut self.decision,
            round,
            label,
            files,
            quiet,
        };
        let mut b = kind.begin(t)?;
        self.later = b.model.take();
        if !b.runs {
            self.schedule.end_before(entry);
        }
        Ok(b)
    }

    /// From the first later stage on, train without the validation views
    /// (`validation_every`); `fresh`: the view order starts anew over the
    /// views left (false where a checkpoint's order, already over them, is
    /// kept).
    pub fn hold_out_validation(&mut self, fresh: bool) {
        if self.held_out || self.cfg.validation_every == 0 {
            return;
        }
        self.views.hold_out(self.cfg.validation_every);
        if fresh {
            self.stack.clear();
        }
        self.held_out = true;
    }

    /// One training iteration.
    pub fn step(&mut self, profile: bool) -> Result<StepReport> {
        let it = self.iteration + 1;
        let (stage, stage_it) = self.schedule.at(it).context("training is already complete")?;
        if stage == Stage::SCATTERING {
            let view = self.next_view();
            let (out, reset) = scattering::stage::iterate(&mut self.scattering, &self.cfg, &self.views, it, view, profile)?;
            self.iteration = it;
            return Ok(StepReport {
                iteration: it,
                stage,
                view,
                loss: out.loss,
                values: out.values,
                gaussians: self.scattering.set.len(),
                densified: out.densified,
                opacity_reset: reset,
                timings: out.timings,
            });
        }
        if self.later.as_ref().map(|m| m.stage()) != Some(stage) {
            bail!("Stage {} has not begun (Trainer::begin_next)", stage.name());
        }
        let view = self.next_view();
        let x = Iteration { global: it, stage: stage_it, view, profile };
        let shared = Shared { cfg: &self.cfg, views: &self.views, scattering: &mut self.scattering, cache: &mut self.cache };
        let model = self.later.as_mut().context("a later stage")?;
        let out = model.iterate(shared, &x)?;
        self.iteration = it;
        Ok(StepReport {
            iteration: it,
            stage,
            view,
            loss: out.loss,
            values: out.values,
            gaussians: model.set().len(),
            densified: out.densified,
            opacity_reset: false,
            timings: out.timings,
        })
    }

    /// Render `cam` with the current model: in Stages II and III the composite, with
    /// the geometry planes of the reflection set where it decides a pixel
    /// ([`reflection_decides`]) and of the scattering set elsewhere, and both layers.
    pub fn render(&mut self, cam: &Camera) -> Result<Rendered> {
        let stage1 = self.sh_degree(self.iteration.min(self.cfg.iterations));
        // The later stage says which degree it composites with.
        let sh = self.later.as_ref().and_then(|m| by_stage(m.stage())).map_or(stage1, |k| k.scattering_sh(&self.cfg, stage1));
        let scat = self.scattering.render(cam, sh, &self.views.background)?;
        let n = (cam.width * cam.height) as usize;
        let Some(model) = self.later.as_mut() else {
            return Ok(scat);
        };
        let colour = Buffer::from_slice(&self.views.ctx, "render.scat_colour", &scat.planes[..3 * n])?;
        let refl = model.render(cam, &colour)?;
        let mut planes = scat.planes.clone();
        planes[..3 * n].copy_from_slice(&refl.composite[..3 * n]);
        let gate = self.normal_gate();
        let decides: Vec<usize> = (0..n).filter(|&i| reflection_decides(&refl, i, gate)).collect();
        for p in [Plane::Alpha, Plane::Depth, Plane::Normal(0), Plane::Normal(1), Plane::Normal(2), Plane::Median, Plane::Distortion] {
            let k = p.index(3) as usize;
            let src = refl.refl_plane(p);
            for &i in &decides {
                planes[k * n + i] = src[i];
            }
        }
        Ok(Rendered { width: cam.width, height: cam.height, planes, layers: Some(Box::new((scat, refl))) })
    }

    /// The reflection weight R a pixel of the reflection set needs to decide
    /// the output geometry: `reflection.normal_min_r` for a set seeded from
    /// glass masks, `reflection.residual_normal_min_r` for one seeded without.
    pub fn normal_min_r(&self) -> f32 {
        let rc = &self.cfg.reflection;
        match &self.decision {
            Some(d) if d.seed_mask_source.is_none() => rc.residual_normal_min_r,
            _ => rc.normal_min_r,
        }
    }

    /// The alpha and R ([`Trainer::normal_min_r`]) a pixel of the
    /// reflection set needs to decide the output geometry.
    pub fn normal_gate(&self) -> NormalGate {
        NormalGate { min_alpha: self.cfg.reflection.normal_min_alpha, min_r: self.normal_min_r() }
    }

    /// Current Gaussians on the host.
    pub fn gaussians(&self) -> Result<HostGaussians> {
        self.scattering.set.params.download()
    }
}
