//! The trainer: a trainable scattering set driven through an explicit stage
//! schedule. Stage I (scattering only) is implemented; the reflection set and
//! Stages II–III add their own `Stage` variants and per-stage step functions
//! without changing the loop, the checkpoint or the outputs.
//!
//! One iteration is two GPU submissions: the forward of one view (then an
//! 8-byte read-back that grows the frame and re-runs it if it overflowed),
//! and loss + backward + densification statistics + Adam. The loss partial
//! sums (a few hundred bytes) come back for the log. Densification runs on
//! the GPU every `densify_interval` iterations.

use super::config::TrainConfig;
use super::init::{gaussians_from_points, random_points};
use super::rng::Rng;
use crate::data::Dataset;
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder, Timing};
use tgs_pipelines::{Adam, AdamGroup, Camera, DensifyParams, Densifier, Features, Frame, HostGaussians, ImageLoss, LossScratch, LossValues, LossWeights, Plane, Rasterizer, TrainableSet};

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

/// Render planes of one view, downloaded.
pub struct Rendered {
    pub width: u32,
    pub height: u32,
    /// Planes in the rasterizer's order (see `Plane`).
    pub planes: Vec<f32>,
}

impl Rendered {
    pub fn plane(&self, p: Plane) -> &[f32] {
        let n = (self.width * self.height) as usize;
        let i = p.index(3) as usize;
        &self.planes[i * n..(i + 1) * n]
    }
}

struct ViewBuffers {
    frame: Frame,
    loss: LossScratch,
}

pub struct Trainer {
    ctx: Arc<Context>,
    pub cfg: TrainConfig,
    pub schedule: Schedule,
    raster: Rasterizer,
    loss: ImageLoss,
    adam: Adam,
    densifier: Densifier,
    pub set: TrainableSet,
    targets: Vec<Buffer<f32>>,
    cameras: Vec<Camera>,
    sizes: HashMap<(u32, u32), ViewBuffers>,
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
        let raster = Rasterizer::new(ctx, 3, Features::Sh { degree: cfg.sh_degree })?;
        let set = TrainableSet::new(ctx, g)?;
        let targets = data.train.iter().map(|v| Buffer::from_slice(ctx, "train.target", &v.image.planar())).collect::<Result<Vec<_>>>()?;
        let cameras = data.train.iter().map(|v| v.camera).collect();
        let (extent, _) = data.extent();
        Ok(Trainer {
            ctx: ctx.clone(),
            schedule: Schedule::from_config(&cfg),
            raster,
            loss: ImageLoss::new(ctx)?,
            adam: Adam::new(ctx, cfg.adam_eps)?,
            densifier: Densifier::new(ctx)?,
            set,
            targets,
            cameras,
            sizes: HashMap::new(),
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

    /// Run the forward of `cam` until it fits its frame.
    fn forward(&mut self, cam: &Camera, sh: u32, profile: bool) -> Result<Vec<Timing>> {
        let b = view_buffers(&mut self.sizes, &self.raster, &self.loss, self.set.len(), cam.width, cam.height)?;
        self.raster.forward(&self.set.params, cam, &self.background, sh, &mut b.frame, profile)
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
            let mut rec = Recorder::new(&self.ctx)?;
            self.densifier.record_opacity_reset(&mut rec, &self.set, 0.01)?;
            rec.submit_and_wait()?;
        }
        let mut report = match stage {
            Stage::Scattering => self.step_scattering(it, profile)?,
        };
        report.opacity_reset = reset;
        Ok(report)
    }

    fn step_scattering(&mut self, it: u32, profile: bool) -> Result<StepReport> {
        let cfg = self.cfg.clone();
        let view = self.next_view();
        let cam = self.cameras[view as usize];
        let sh = self.sh_degree(it);
        let mut timings = self.forward(&cam, sh, profile)?;

        let weights = LossWeights {
            ssim: cfg.lambda_ssim,
            normal: if it > cfg.normal_from { cfg.lambda_normal } else { 0.0 },
            dist: if it > cfg.dist_from { cfg.lambda_dist } else { 0.0 },
        };
        let lr_means = self.lr_means(it);
        let stats = it < cfg.densify_until;
        let ctx = self.ctx.clone();
        let target = &self.targets[view as usize];
        let b = self.sizes.get_mut(&(cam.width, cam.height)).context("view buffers missing after the forward")?;
        let mut rec = if profile { Recorder::with_profiling(&ctx, 256)? } else { Recorder::new(&ctx)? };
        self.loss.record(&mut rec, &b.frame, target, &cam, &weights, &mut b.loss)?;
        self.raster.record_backward(&mut rec, &self.set.params, &self.set.grads, sh, &b.frame)?;
        if stats {
            let sc = rec.begin_scope("densify.stats");
            self.densifier.record_stats(&mut rec, &self.set, &b.frame)?;
            rec.end_scope(sc);
        }
        let sc = rec.begin_scope("adam");
        let s = &self.set;
        let n = s.len() as usize;
        let k = s.params.coeffs;
        let groups = [
            (&s.params.means, &s.grads.means, &s.m.means, &s.v.means, 3 * n, AdamGroup::single(lr_means)),
            (&s.params.log_scales, &s.grads.log_scales, &s.m.log_scales, &s.v.log_scales, 2 * n, AdamGroup::single(cfg.lr_scales)),
            (&s.params.quats, &s.grads.quats, &s.m.quats, &s.v.quats, 4 * n, AdamGroup::single(cfg.lr_quats)),
            (&s.params.opacity, &s.grads.opacity, &s.m.opacity, &s.v.opacity, n, AdamGroup::single(cfg.lr_opacity)),
            (&s.params.features, &s.grads.features, &s.m.features, &s.v.features, 3 * k as usize * n, AdamGroup { lr: cfg.lr_features_dc, lr_rest: cfg.lr_features_rest, stride: 3 * k, split: 3 }),
        ];
        for (p, g, m, v, len, group) in groups {
            self.adam.record(&mut rec, p, g, m, v, len, &group, it as u64)?;
        }
        rec.end_scope(sc);
        timings.extend(rec.submit_and_wait()?);
        let values = b.loss.values()?;
        let loss = values.photometric(cfg.lambda_ssim as f64)
            + if weights.normal != 0.0 { weights.normal as f64 * values.normal } else { 0.0 };

        let mut densified = None;
        if it < cfg.densify_until && it > cfg.densify_from && it % cfg.densify_interval == 0 {
            let p = DensifyParams {
                grad_threshold: cfg.densify_grad,
                dense_scale: cfg.percent_dense * self.extent,
                opacity_min: cfg.prune_opacity,
                prune_big: it > cfg.opacity_reset_interval,
                big_screen: cfg.max_screen_size,
                big_world: cfg.max_world_size * self.extent,
                grow: self.set.len() < cfg.max_gaussians,
                seed: (cfg.seed as u32) ^ it.wrapping_mul(0x9E37_79B9),
            };
            let r = self.densifier.densify(&mut self.set, &p)?;
            if r.after == 0 && r.before > 0 {
                bail!(
                    "iteration {it}: densification pruned all {} Gaussians (opacity below prune_opacity {}; an opacity reset too close before a densification does this)",
                    r.before,
                    cfg.prune_opacity
                );
            }
            densified = Some((r.before, r.after));
        }
        self.iteration = it;
        Ok(StepReport { iteration: it, stage: Stage::Scattering, view, loss, values, gaussians: self.set.len(), densified, opacity_reset: false, timings })
    }

    /// Render `cam` with the current Gaussians (all output planes).
    pub fn render(&mut self, cam: &Camera) -> Result<Rendered> {
        let sh = self.sh_degree(self.iteration);
        self.forward(cam, sh, false)?;
        let b = &self.sizes[&(cam.width, cam.height)];
        Ok(Rendered { width: cam.width, height: cam.height, planes: b.frame.out.download()? })
    }

    /// Intersections (Gaussian, tile pairs) of the last view rendered.
    pub fn last_intersections(&self) -> u32 {
        self.sizes.values().map(|b| b.frame.last_intersections).max().unwrap_or(0)
    }

    /// Current Gaussians on the host.
    pub fn gaussians(&self) -> Result<HostGaussians> {
        self.set.params.download()
    }
}

/// The frame and loss buffers for one image size, (re)made when the set
/// outgrew the frame (the intersection capacity carries over).
fn view_buffers<'a>(sizes: &'a mut HashMap<(u32, u32), ViewBuffers>, raster: &Rasterizer, loss: &ImageLoss, n: u32, w: u32, h: u32) -> Result<&'a mut ViewBuffers> {
    let old = sizes.get(&(w, h)).map(|b| (b.frame.max_gaussians, b.frame.capacity));
    if old.is_none_or(|(max_g, _)| max_g < n) {
        let old_cap = old.map(|o| o.1).unwrap_or(0);
        let max_g = n + n / 2 + 1024;
        let cap = old_cap.max((2 * max_g).min(raster.max_capacity()));
        let frame = raster.frame(w, h, max_g, cap)?;
        let loss = loss.scratch(w, h, 3)?;
        sizes.insert((w, h), ViewBuffers { frame, loss });
    }
    Ok(sizes.get_mut(&(w, h)).unwrap())
}
