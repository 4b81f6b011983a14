//! The trainer: the loop and the schedule. It owns the training views, the
//! view order, the iteration count and the stage schedule, and drives one
//! model per stage (`scattering::ScatteringModel` for Stage I; the
//! reflection set and the light field come as models beside it). Models
//! never refer to the trainer: each step gets what it needs as arguments.

use super::config::TrainConfig;
use super::init::{gaussians_from_points, random_points};
use super::rng::Rng;
use super::scattering::{ScatteringModel, StepInput};
use crate::data::Dataset;
use anyhow::{Context as _, Result};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Timing};
use tgs_pipelines::{Camera, HostGaussians, LossValues};

pub use super::scattering::Rendered;

/// Training stages (paper §3–4). Only Stage I exists so far.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Stage {
    /// Stage I: the scattering set alone (2DGS).
    #[default]
    Scattering,
}

impl Stage {
    pub fn name(self) -> &'static str {
        match self {
            Stage::Scattering => "I",
        }
    }
}

/// The stage schedule: each stage with its iteration count, run in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Schedule {
    pub stages: Vec<(Stage, u32)>,
}

impl Schedule {
    pub fn from_config(cfg: &TrainConfig) -> Schedule {
        Schedule { stages: vec![(Stage::Scattering, cfg.iterations)] }
    }
    pub fn total(&self) -> u32 {
        self.stages.iter().map(|s| s.1).sum()
    }
    /// The stage of global iteration `it` (1-based) and the iteration within it.
    pub fn at(&self, it: u32) -> Option<(Stage, u32)> {
        let mut start = 0;
        for &(s, n) in &self.stages {
            if it > start && it <= start + n {
                return Some((s, it - start));
            }
            start += n;
        }
        None
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
    targets: Vec<Buffer<f32>>,
    cameras: Vec<Camera>,
    /// Completed iterations.
    pub iteration: u32,
    pub rng: Rng,
    /// Training views not yet used in this pass (popped from the back).
    pub stack: Vec<u32>,
    pub extent: f32,
    pub background: [f32; 3],
}

impl Trainer {
    /// A trainer with Gaussians initialised from the dataset's points (or
    /// random points when it has none).
    pub fn new(ctx: &Arc<Context>, cfg: TrainConfig, data: &Dataset) -> Result<Trainer> {
        let mut rng = Rng::new(cfg.seed);
        let points = match &data.points {
            Some(p) if !p.positions.is_empty() => p.clone(),
            _ => random_points(cfg.init_points, cfg.init_half_extent, &mut rng),
        };
        let g = gaussians_from_points(&points, cfg.sh_degree, &mut rng);
        Self::with_gaussians(ctx, cfg, data, &g, rng)
    }

    pub fn with_gaussians(ctx: &Arc<Context>, cfg: TrainConfig, data: &Dataset, g: &HostGaussians, rng: Rng) -> Result<Trainer> {
        cfg.validate()?;
        let targets = data.train.iter().map(|v| Buffer::from_slice(ctx, "train.target", &v.image.planar())).collect::<Result<Vec<_>>>()?;
        let cameras = data.train.iter().map(|v| v.camera).collect();
        let (extent, _) = data.extent();
        Ok(Trainer {
            schedule: Schedule::from_config(&cfg),
            scattering: ScatteringModel::new(ctx, g, cfg.sh_degree, cfg.adam_eps)?,
            targets,
            cameras,
            iteration: 0,
            rng,
            stack: Vec::new(),
            extent,
            background: data.background,
            cfg,
        })
    }

    pub fn done(&self) -> bool {
        self.iteration >= self.schedule.total()
    }

    /// Active SH degree at iteration `it` (one more every `sh_interval`).
    pub fn sh_degree(&self, it: u32) -> u32 {
        (it / self.cfg.sh_interval).min(self.cfg.sh_degree)
    }

    /// Position learning rate at iteration `it`: log-linear over the stage, x extent.
    pub fn lr_means(&self, it: u32) -> f32 {
        let t = (it as f64 / self.cfg.iterations.max(1) as f64).clamp(0.0, 1.0);
        let (a, b) = (self.cfg.lr_means.max(1e-30) as f64, self.cfg.lr_means_final.max(1e-30) as f64);
        ((a.ln() * (1.0 - t) + b.ln() * t).exp() * self.extent as f64) as f32
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

    /// One training iteration.
    pub fn step(&mut self, profile: bool) -> Result<StepReport> {
        let it = self.iteration + 1;
        let (stage, _) = self.schedule.at(it).context("training is already complete")?;
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
        let out = match stage {
            Stage::Scattering => self.scattering.step(&self.cfg, &input)?,
        };
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

    /// Render `cam` with the current Gaussians (all output planes).
    pub fn render(&mut self, cam: &Camera) -> Result<Rendered> {
        let sh = self.sh_degree(self.iteration);
        self.scattering.render(cam, sh, &self.background)
    }

    /// Current Gaussians on the host.
    pub fn gaussians(&self) -> Result<HostGaussians> {
        self.scattering.set.params.download()
    }
}
