//! Stage I's model: the scattering Gaussian set (2DGS surfels) with what
//! trains it: the rasterizer, the image loss, Adam and density control.
//! The trainer decides which view, which iteration and which settings; this
//! model records the GPU work of one step (one submission: forward, loss,
//! backward, densification statistics and Adam, the updates gated on the GPU
//! by whether the view fitted its frame, the step re-run after the frame
//! grew when it did not) and densifies when asked. It never refers to the
//! trainer.

use crate::train::config::TrainConfig;
use crate::train::stages::kept_views::{KeepAs, KeptViews};
use crate::train::stages::rendered::Rendered;
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder, Timing};
use tgs_pipelines::{
    Adam, AdamGroup, Camera, Densifier, DensifyParams, Features, Frame, HostGaussians, ImageLoss, LossScratch, LossValues, LossWeights, Moments, Plane, Rasterizer, SetGuard,
    TrainableSet,
};

/// What the trainer passes for one step of this model.
pub struct StepInput<'a> {
    /// Global iteration (1-based), the Adam step count.
    pub iteration: u32,
    pub camera: &'a Camera,
    /// The view's image, planar RGB.
    pub target: &'a Buffer<f32>,
    /// Active SH degree.
    pub sh_degree: u32,
    /// Position learning rate (already scaled by the scene extent).
    pub lr_means: f32,
    pub background: [f32; 3],
    /// Scene extent (densification thresholds are relative to it).
    pub extent: f32,
    pub profile: bool,
}

/// The Adam step of [`ScatteringModel::record_backward_external`]: the
/// active SH degree, the position rate, the step's count for Adam's bias
/// correction, and whether only the SH colour is stepped.
#[derive(Clone, Copy, Debug)]
pub struct ExternalStep {
    pub sh_degree: u32,
    pub lr_means: f32,
    pub iteration: u32,
    pub colour_only: bool,
}

/// What one step did.
pub struct StepOutput {
    pub loss: f64,
    pub values: LossValues,
    /// Gaussian count before and after, when this step densified.
    pub densified: Option<(u32, u32)>,
    pub timings: Vec<Timing>,
}

struct ViewBuffers {
    frame: Frame,
    loss: LossScratch,
}

pub struct ScatteringModel {
    ctx: Arc<Context>,
    raster: Rasterizer,
    loss: ImageLoss,
    adam: Adam,
    densifier: Densifier,
    pub set: TrainableSet,
    /// Frame and loss buffers per image size.
    sizes: HashMap<(u32, u32), ViewBuffers>,
    /// Step with Adam fused into the backward's per-Gaussian reduce, where
    /// the device can (off: the backward writes gradients and a separate
    /// Adam pass steps them; the parameters are bit-identical either way).
    /// By default on CPU devices only, where it was measured faster
    /// (perf/RESULTS.md, eighth entry); on an H200 at a million Gaussians
    /// the fused reduce took 11.6 ms against 2.9 + 0.5 ms for the reduce
    /// and Adam apart (thirtieth entry).
    pub fuse_adam: bool,
    /// Training views' blend weights kept while only the colour trains
    /// (Stage III; cleared by any step of Stage I's).
    kept: KeptViews,
    /// The training view the last forward rendered from its kept weights,
    /// or in full with its weights captured (its backward then uses them).
    from_weights: Option<u32>,
    /// The divergence guard recorded into every step (the driver's; off
    /// for benches and tests that step the model themselves).
    pub guard: Option<SetGuard>,
}

impl ScatteringModel {
    pub fn new(ctx: &Arc<Context>, g: &HostGaussians, sh_degree: u32, adam_eps: f32) -> Result<ScatteringModel> {
        Ok(ScatteringModel {
            ctx: ctx.clone(),
            raster: Rasterizer::new(ctx, 3, Features::Sh { degree: sh_degree })?,
            loss: ImageLoss::new(ctx)?,
            adam: Adam::new(ctx, adam_eps)?,
            densifier: Densifier::new(ctx)?,
            set: TrainableSet::new(ctx, g)?,
            sizes: HashMap::new(),
            fuse_adam: ctx.caps().is_cpu(),
            kept: KeptViews::default(),
            from_weights: None,
            guard: None,
        })
    }

    /// Run the forward of `cam` until it fits its frame (Stage III drives
    /// the scattering set through this, [`Self::frame_buffers`] and
    /// [`Self::record_backward_external`]).
    pub fn forward_view(&mut self, cam: &Camera, sh: u32, background: &[f32; 3], profile: bool) -> Result<Vec<Timing>> {
        self.forward(cam, sh, background, profile)
    }

    /// The forward of training view `at.view` while the geometry is frozen
    /// (Stage III with the colour alone training): the colour planes from
    /// its kept blend weights, or in full, its weights then captured (kept
    /// within the budget, or for this step); only the colour planes of a
    /// render from kept weights are written. [`Self::record_backward_external`]
    /// then takes the colour's gradient from the same weights.
    pub fn forward_view_kept(&mut self, at: KeepAs, cam: &Camera, sh: u32, background: &[f32; 3], profile: bool) -> Result<Vec<Timing>> {
        let Some(k) = self.kept.get(at.view) else {
            let t = self.forward(cam, sh, background, profile)?;
            let b = self.sizes.get(&(cam.width, cam.height)).context("no render of this size yet")?;
            let (raster, set) = (&self.raster, &self.set);
            self.kept.capture(at, |budget| raster.keep_weights(&set.params, &b.frame, budget, false));
            if self.kept.get(at.view).is_some() {
                self.from_weights = Some(at.view);
            }
            return Ok(t);
        };
        let b = view_buffers(&mut self.sizes, &self.raster, &self.loss, self.set.len(), cam.width, cam.height)?;
        let mut rec = Recorder::profiled_if(&self.ctx, profile)?;
        self.raster.record_forward_weights(&mut rec, tgs_pipelines::Splats::own(&self.set.params, sh), cam, background, &b.frame, k)?;
        let t = rec.submit_and_wait()?;
        self.from_weights = Some(at.view);
        Ok(t)
    }

    /// The last forward's output planes (colour first) and their gradient
    /// buffer for a `width` x `height` view.
    pub fn frame_buffers(&self, width: u32, height: u32) -> Result<(&Buffer<f32>, &Buffer<f32>)> {
        let b = self.sizes.get(&(width, height)).context("no render of this size yet")?;
        Ok((&b.frame.out, &b.frame.grad_out))
    }

    /// Record the backward of the last forward of `cam` from gradients a
    /// later stage wrote into [`Self::frame_buffers`]' gradient planes, and
    /// an Adam step (Stage I's rates, positions at `step.lr_means`; no
    /// densification statistics). With `step.colour_only` the step covers
    /// the SH colour alone: the geometry and opacity, and their Adam
    /// moments, stay as they are.
    pub fn record_backward_external(&self, rec: &mut Recorder, cfg: &TrainConfig, cam: &Camera, step: &ExternalStep) -> Result<()> {
        let ExternalStep { sh_degree: sh, lr_means, iteration: it, colour_only } = *step;
        let b = self.sizes.get(&(cam.width, cam.height)).context("no render of this size yet")?;
        let groups = self.groups(cfg, lr_means, sh);
        let fused = self.fuse_adam && self.raster.can_fuse_adam();
        let weights = self.from_weights.and_then(|v| self.kept.get(v));
        if let (true, Some(k)) = (colour_only, weights) {
            let s = &self.set;
            if fused {
                let c = self.adam.reduce_constants(s, &groups, it as u64)?;
                return self.raster.record_colour_adam_weights(rec, &s.params, Moments { m: &s.m, v: &s.v, adam: &c, features_only: true }, sh, &b.frame, k);
            }
            self.raster.record_backward_colour_weights(rec, tgs_pipelines::Splats::own(&s.params, sh), &s.grads, &s.grads.features, &b.frame, k)?;
            let sc = rec.begin_scope("adam");
            self.adam.record_set_features(rec, s, &groups[4], it as u64)?;
            rec.end_scope(sc);
            return Ok(());
        }
        if colour_only && fused {
            // The colour's Adam step in the reduce (the same result as the
            // two passes below, bit for bit: tests/tests/train_kernels.rs).
            let c = self.adam.reduce_constants(&self.set, &groups, it as u64)?;
            let s = &self.set;
            return self.raster.record_backward_adam(rec, &s.params, Moments { m: &s.m, v: &s.v, adam: &c, features_only: true }, sh, &b.frame, None);
        }
        if colour_only {
            self.raster.record_backward_colour(rec, &self.set.params, &self.set.grads, sh, &b.frame)?;
        } else {
            self.raster.record_backward(rec, &self.set.params, &self.set.grads, sh, &b.frame)?;
        }
        let sc = rec.begin_scope("adam");
        if colour_only {
            self.adam.record_set_features(rec, &self.set, &groups[4], it as u64)?;
        } else {
            self.adam.record_set(rec, &self.set, &groups, it as u64)?;
        }
        rec.end_scope(sc);
        Ok(())
    }

    /// Stage I's Adam groups at active SH degree `sh`: the coefficients of
    /// higher degrees are not stepped (their gradients are zero until then).
    fn groups(&self, cfg: &TrainConfig, lr_means: f32, sh: u32) -> [AdamGroup; 5] {
        let k = self.set.params.coeffs;
        let active = (sh + 1) * (sh + 1);
        [
            AdamGroup::single(lr_means),
            AdamGroup::single(cfg.lr_scales),
            AdamGroup::single(cfg.lr_quats),
            AdamGroup::single(cfg.lr_opacity),
            AdamGroup { active: 3 * active.min(k), ..AdamGroup::split(cfg.lr_features_dc, cfg.lr_features_rest, 3 * k, 3) },
        ]
    }

    /// Run the forward of `cam` until it fits its frame.
    fn forward(&mut self, cam: &Camera, sh: u32, background: &[f32; 3], profile: bool) -> Result<Vec<Timing>> {
        self.from_weights = None;
        let b = view_buffers(&mut self.sizes, &self.raster, &self.loss, self.set.len(), cam.width, cam.height)?;
        self.raster.forward(&self.set.params, cam, background, sh, &mut b.frame, profile)
    }

    /// One training step on one view, in one submission: forward, loss,
    /// backward, densification statistics and Adam, the last two gated on
    /// the GPU by whether the view fitted its frame; when it did not, nothing
    /// was updated, the frame grows and the step runs again. Densifies when
    /// `cfg`'s schedule says so (its own submissions).
    pub fn step(&mut self, cfg: &TrainConfig, x: &StepInput) -> Result<StepOutput> {
        let (it, cam, sh) = (x.iteration, x.camera, x.sh_degree);
        let weights =
            LossWeights { ssim: cfg.lambda_ssim, normal: if it > cfg.normal_from { cfg.lambda_normal } else { 0.0 }, dist: if it > cfg.dist_from { cfg.lambda_dist } else { 0.0 } };
        let stats = it < cfg.densify_until;
        let groups = self.groups(cfg, x.lr_means, sh);
        self.kept.clear();
        self.from_weights = None;
        let fused = self.fuse_adam && self.raster.can_fuse_adam();
        let (timings, values) = loop {
            let b = view_buffers(&mut self.sizes, &self.raster, &self.loss, self.set.len(), cam.width, cam.height)?;
            let mut rec = Recorder::profiled_if(&self.ctx, x.profile)?;
            self.raster.record_forward(&mut rec, &self.set.params, cam, &x.background, sh, &b.frame)?;
            self.loss.record(&mut rec, &b.frame, x.target, cam, &weights, &mut b.loss)?;
            // The gate's slots: what steps the parameters, then the
            // densification statistics (which read the backward's
            // screen-space gradients).
            let stats_grid = self.densifier.stats_grid(&self.set);
            let args = if fused {
                // The reduce steps the parameters itself, so it is gated.
                let args = self.raster.record_fit_gate(&mut rec, &b.frame, &[self.raster.reduce_grid(self.set.len()), stats_grid])?;
                let c = self.adam.reduce_constants(&self.set, &groups, it as u64)?;
                let s = &self.set;
                self.raster.record_backward_adam(&mut rec, &s.params, Moments { m: &s.m, v: &s.v, adam: &c, features_only: false }, sh, &b.frame, Some(&args[0]))?;
                args
            } else {
                self.raster.record_backward(&mut rec, &self.set.params, &self.set.grads, sh, &b.frame)?;
                let mut grids = self.adam.set_grids(&self.set, &groups).to_vec();
                grids.push(stats_grid);
                self.raster.record_fit_gate(&mut rec, &b.frame, &grids)?
            };
            let (stats_arg, adam_args) = args.split_last().context("fit gate slots")?;
            if stats {
                let sc = rec.begin_scope("densify.stats");
                self.densifier.record_stats_gated(&mut rec, &self.set, &b.frame, stats_arg)?;
                rec.end_scope(sc);
            }
            if !fused {
                let sc = rec.begin_scope("adam");
                self.adam.record_set_gated(&mut rec, &self.set, &groups, it as u64, adam_args)?;
                rec.end_scope(sc);
            }
            if let Some(g) = &self.guard {
                let sc = rec.begin_scope("guard");
                g.record(&mut rec, &self.set)?;
                rec.end_scope(sc);
            }
            let t = rec.submit_and_wait()?;
            if self.raster.fit(&mut b.frame)? {
                break (t, b.loss.values()?);
            }
        };
        let loss = values.photometric(cfg.lambda_ssim as f64) + if weights.normal != 0.0 { weights.normal as f64 * values.normal } else { 0.0 };

        let mut densified = None;
        if it < cfg.densify_until && it > cfg.densify_from && it % cfg.densify_interval == 0 {
            let p = DensifyParams {
                grad_threshold: cfg.densify_grad,
                dense_scale: cfg.percent_dense * x.extent,
                opacity_min: cfg.prune_opacity,
                prune_big: it > cfg.opacity_reset_interval,
                big_screen: cfg.max_screen_size,
                big_world: cfg.max_world_size * x.extent,
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
        Ok(StepOutput { loss, values, densified, timings })
    }

    /// Cap every opacity at 0.01 (and clear its Adam moments).
    pub fn reset_opacity(&mut self) -> Result<()> {
        self.kept.clear();
        self.from_weights = None;
        let mut rec = Recorder::new(&self.ctx)?;
        self.densifier.record_opacity_reset(&mut rec, &self.set, 0.01)?;
        rec.submit_and_wait()?;
        Ok(())
    }

    /// Render `cam` with the current Gaussians (all output planes).
    pub fn render(&mut self, cam: &Camera, sh: u32, background: &[f32; 3]) -> Result<Rendered> {
        self.forward(cam, sh, background, false)?;
        let b = &self.sizes[&(cam.width, cam.height)];
        Ok(Rendered { width: cam.width, height: cam.height, planes: b.frame.out.download()?, layers: None })
    }

    /// Render `cam` and copy its colour (3 planes, background blended in) into `dst`.
    pub fn render_color_into(&mut self, cam: &Camera, sh: u32, background: &[f32; 3], dst: &Buffer<f32>) -> Result<()> {
        self.forward(cam, sh, background, false)?;
        let b = &self.sizes[&(cam.width, cam.height)];
        let mut rec = Recorder::new(&self.ctx)?;
        rec.copy(&b.frame.out.binding(), &dst.binding(), 12 * b.frame.pixels() as u64)?;
        rec.submit_and_wait()?;
        Ok(())
    }

    /// One plane (`Plane` order, 3 colour channels) of the last render of
    /// a `width` x `height` view, downloaded.
    pub fn last_plane(&self, width: u32, height: u32, plane: Plane) -> Result<Vec<f32>> {
        let b = self.sizes.get(&(width, height)).context("no render of this size yet")?;
        let n = b.frame.pixels();
        b.frame.out.download_range(plane.index(3) as usize * n, n)
    }

    pub fn rasterizer(&self) -> &Rasterizer {
        &self.raster
    }

    /// Intersections (Gaussian, tile pairs) of the last view rendered.
    pub fn last_intersections(&self) -> u32 {
        self.sizes.values().map(|b| b.frame.last_intersections).max().unwrap_or(0)
    }
}

/// The frame and loss buffers for one image size, (re)made when the set
/// outgrew the frame (the intersection capacity carries over).
fn view_buffers<'a>(sizes: &'a mut HashMap<(u32, u32), ViewBuffers>, raster: &Rasterizer, loss: &ImageLoss, n: u32, w: u32, h: u32) -> Result<&'a mut ViewBuffers> {
    let old = sizes.get(&(w, h)).map(|b| (b.frame.max_gaussians, b.frame.capacity));
    if old.is_none_or(|(max_g, _)| max_g < n) {
        let old_cap = old.map(|o| o.1).unwrap_or(0);
        let max_g = n + n / 2 + 1024;
        let cap = old_cap.max(raster.initial_capacity(max_g));
        let frame = raster.frame(w, h, max_g, cap)?;
        let loss = loss.scratch(w, h, 3)?;
        sizes.insert((w, h), ViewBuffers { frame, loss });
    }
    Ok(sizes.get_mut(&(w, h)).unwrap())
}
