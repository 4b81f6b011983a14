//! Benchmark of whole training iterations (forward, loss, backward, reduce,
//! Adam) on Brush's workload, the spheres scene (`scene::spheres`): 20
//! views, SH degree 3 active from the start, densification off so the
//! Gaussian count stays at the initial points. [`Workload::REAL_SCALE`]
//! is the same scene at the size users train: a Mip-NeRF 360 frame
//! (1237x822) and a million Gaussians. Wall time per iteration
//! includes all host work (submissions, read-backs); a second, profiled
//! series gives GPU ms per kernel. Shared by `tgs bench train` and
//! `cargo bench --bench train`.

use crate::bench::{average, KernelTime};
use crate::scene::spheres::{self, SpheresSpec};
use crate::train::args::load_dataset;
use crate::train::checkpoint;
use crate::train::rundir::{CHECKPOINT, STAGE_ONE_CHECKPOINT};
use crate::train::{TrainConfig, Trainer};
use anyhow::{ensure, Context as _, Result};
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::Context;

/// The SH degree every workload trains at (active from iteration 3).
const SH_DEGREE: u32 = 3;

/// Brush's whole-iteration time on this project's 2-core lavapipe machine
/// (DEVELOPERS.md), seconds, for (resolution, Gaussians).
pub const BRUSH_LAVAPIPE_S: [((u32, u32), f64); 2] = [((128, 10_000), 0.9), ((256, 50_000), 4.5)];

#[derive(Clone, Debug, Serialize)]
pub struct TrainBench {
    pub device: String,
    pub width: u32,
    pub height: u32,
    pub views: u32,
    pub gaussians: u32,
    pub sh_degree: u32,
    pub warmup: u32,
    pub iterations: u32,
    /// Host wall time per iteration, ms: mean and best over the timed series.
    pub wall_ms: f64,
    pub wall_ms_best: f64,
    pub it_per_s: f64,
    /// Queue submissions (each waited for) per timed iteration.
    pub submissions_per_iteration: f64,
    /// GPU ms per iteration by stage (from the profiled series): forward
    /// (projection, sorts, binning, rasterization), loss (SSIM + gradient
    /// planes), backward (rasterizer backward + per-Gaussian reduce, with the
    /// Adam step when `adam_fused`), Adam (its own pass, or only the gate).
    pub forward_ms: f64,
    pub loss_ms: f64,
    pub backward_ms: f64,
    pub adam_ms: f64,
    pub gpu_ms: f64,
    /// Whether Adam ran inside the per-Gaussian reduce.
    pub adam_fused: bool,
    /// Every timed scope (nested sort/scan passes included), ms per iteration.
    pub kernels: Vec<KernelTime>,
    /// Rasterized (Gaussian, tile) pairs of the last view.
    pub intersections: u32,
    /// Device bytes per intersection of frame capacity (keys, values, ids,
    /// tile-sort arrays, gradient record).
    pub bytes_per_intersection: u64,
    /// Peak device memory of the tgs context over the run (dataset images,
    /// Gaussians, Adam state, frames), MiB.
    pub peak_memory_mib: f64,
    /// Brush's time for this workload as timed on the reference machine
    /// (lavapipe, 2 cores; DEVELOPERS.md), when it is one of the two
    /// measured there. Not a measurement on this device.
    pub brush_lavapipe_s: Option<f64>,
}

/// What one benchmark trains: the spheres scene at `width` x `height` with
/// `views` training views and `points` Gaussians.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workload {
    pub width: u32,
    pub height: u32,
    pub points: u32,
    pub views: u32,
}

impl Workload {
    /// A Mip-NeRF 360 scene's size as 3DGS/2DGS train it (a frame of about
    /// 1237x822 after the usual 4x downscale, about a million Gaussians);
    /// 8 views: the views only hold images (per-iteration work does not
    /// depend on their number) and 8 keep the images' device memory
    /// (98 MiB) within what every device here allocates.
    pub const REAL_SCALE: Workload = Workload { width: 1237, height: 822, points: 1_000_000, views: 8 };

    /// Brush's workloads: square `res`, `points` Gaussians, 20 views.
    pub fn square(res: u32, points: u32) -> Workload {
        Workload { width: res, height: res, points, views: 20 }
    }
}

/// Top-level scopes of a training step, by stage. Scopes named `sort.*`
/// and `scan.*` are nested inside `raster.*` ones and not summed again.
fn stage_of(name: &str) -> Option<&'static str> {
    match name {
        "raster.backward" | "raster.reduce" => Some("backward"),
        // The gate decides whether Adam runs (one invocation).
        "adam" | "raster.gate" => Some("adam"),
        "densify.stats" => Some("backward"),
        n if n.starts_with("loss.") => Some("loss"),
        n if n.starts_with("raster.") => Some("forward"),
        _ => None,
    }
}

/// Time `iterations` training iterations (after `warmup`) on the spheres
/// scene of workload `w`, Adam fused into the reduce where the device can
/// (`fuse_adam` Some(true)), in its own pass (Some(false)), or as training
/// chooses for the device (None).
pub fn train(ctx: &Arc<Context>, w: Workload, warmup: u32, iterations: u32, fuse_adam: Option<bool>) -> Result<TrainBench> {
    ensure!(iterations > 0, "--iterations must be at least 1");
    ensure!(w.views > 0, "--views must be at least 1");
    ensure!(w.width > 0 && w.height > 0, "--res {}: the image must be at least 1x1", w.width.min(w.height));
    ensure!(w.points > 0, "--points 0: at least one Gaussian is needed");
    let spec = SpheresSpec { width: w.width, height: w.height, points: w.points, train: w.views, ..SpheresSpec::NAMED[0].1 };
    let data = spheres::dataset(&spec)?;
    let profiled = profiled(iterations);
    // SH degree 3 is active from iteration 3 on (sh_interval 1).
    let warmup = warmup.max(3);
    let cfg = TrainConfig { iterations: warmup.saturating_add(iterations).saturating_add(profiled), sh_degree: SH_DEGREE, sh_interval: 1, ..bench_config(w.points) };
    ctx.reset_peak_memory();
    let tr = Trainer::new(ctx, cfg, &data)?;
    let brush_lavapipe_s = BRUSH_LAVAPIPE_S.iter().find(|(k, _)| w.width == w.height && *k == (w.width, w.points) && w.views == 20).map(|(_, s)| *s);
    time(ctx, tr, Series { warmup, iterations, fuse_adam }, (w.width, w.height, spec.train), brush_lavapipe_s)
}

/// Time Stage I iterations on a trained model: the scattering set of the
/// run directory `run` (its Stage I checkpoint where the run went past
/// Stage I, else its checkpoint, later stages' state dropped) on the run's
/// own dataset and settings, densification off so the count stays. The
/// random spheres of [`train`] are small and evenly spread; a trained
/// model's splats are not, and the two can rank a change differently
/// (perf/RESULTS.md, thirty-seventh entry: 8x8 tiles).
pub fn train_from(ctx: &Arc<Context>, run: &Path, warmup: u32, iterations: u32, fuse_adam: Option<bool>) -> Result<TrainBench> {
    ensure!(iterations > 0, "--iterations must be at least 1");
    let stage_one = run.join(STAGE_ONE_CHECKPOINT);
    let path = if stage_one.is_file() { stage_one } else { run.join(CHECKPOINT) };
    ensure!(path.is_file(), "--from {}: no {CHECKPOINT} there (a `tgs train` run directory is expected)", run.display());
    let (mut h, mut arrays) = checkpoint::read(&path)?;
    h.drop_later(&mut arrays).with_context(|| format!("{}", path.display()))?;
    let data = load_dataset(Path::new(&h.dataset), &h.config).with_context(|| format!("--from {}: loading its dataset {}", run.display(), h.dataset))?;
    ensure!(!data.train.is_empty(), "--from {}: its dataset {} has no training views", run.display(), h.dataset);
    let profiled = profiled(iterations);
    // Stage I goes on past the checkpoint with the count fixed.
    let cfg = &mut h.config;
    cfg.iterations = h.iteration.saturating_add(warmup).saturating_add(iterations).saturating_add(profiled + 1);
    cfg.densify_until = 0;
    cfg.max_gaussians = h.n.max(1);
    cfg.init_points = cfg.init_points.min(cfg.max_gaussians);
    cfg.test_interval = 0;
    cfg.checkpoint_interval = 0;
    cfg.stages = "I".into();
    ctx.reset_peak_memory();
    let tr = checkpoint::restore(ctx, &path, (h, arrays), &data)?;
    let (width, height) = (data.train[0].camera.width, data.train[0].camera.height);
    time(ctx, tr, Series { warmup, iterations, fuse_adam }, (width, height, data.train.len() as u32), None)
}

/// The iterations [`time`] runs: untimed, timed, then [`profiled`].
struct Series {
    warmup: u32,
    iterations: u32,
    fuse_adam: Option<bool>,
}

/// The profiled iterations after `iterations` timed ones.
fn profiled(iterations: u32) -> u32 {
    iterations.clamp(1, 5)
}

/// Run `s` on `tr` (frames of `size` = width, height, views) and report.
fn time(ctx: &Arc<Context>, mut tr: Trainer, s: Series, size: (u32, u32, u32), brush_lavapipe_s: Option<f64>) -> Result<TrainBench> {
    let Series { warmup, iterations, fuse_adam } = s;
    let profiled = profiled(iterations);
    let (width, height, views) = size;
    if let Some(f) = fuse_adam {
        tr.scattering.fuse_adam = f;
    }
    let adam_fused = tr.scattering.fuse_adam && tr.scattering.rasterizer().can_fuse_adam();
    for _ in 0..warmup {
        tr.step(false)?;
    }
    let mut walls = Vec::new();
    let submitted = ctx.submissions();
    for _ in 0..iterations {
        let t = Instant::now();
        tr.step(false)?;
        walls.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let submissions_per_iteration = (ctx.submissions() - submitted) as f64 / iterations as f64;
    let mut all = Vec::new();
    let mut intersections = 0;
    for _ in 0..profiled {
        let r = tr.step(true)?;
        all.push(r.timings);
        intersections = tr.scattering.last_intersections();
    }
    let kernels = average(all);
    let stage = |s: &str| kernels.iter().filter(|k| stage_of(&k.name) == Some(s)).map(|k| k.ms).sum::<f64>();
    let (forward_ms, loss_ms, backward_ms, adam_ms) = (stage("forward"), stage("loss"), stage("backward"), stage("adam"));
    let wall_ms = walls.iter().sum::<f64>() / walls.len() as f64;
    Ok(TrainBench {
        device: ctx.caps().describe(),
        width,
        height,
        views,
        gaussians: tr.scattering.set.len(),
        sh_degree: tr.cfg.sh_degree,
        warmup,
        iterations,
        wall_ms,
        wall_ms_best: walls.iter().copied().fold(f64::INFINITY, f64::min),
        it_per_s: 1e3 / wall_ms,
        submissions_per_iteration,
        forward_ms,
        loss_ms,
        backward_ms,
        adam_ms,
        gpu_ms: forward_ms + loss_ms + backward_ms + adam_ms,
        adam_fused,
        kernels,
        intersections,
        bytes_per_intersection: tr.scattering.rasterizer().bytes_per_intersection(),
        peak_memory_mib: ctx.memory_use().peak_bytes as f64 / 1048576.0,
        brush_lavapipe_s,
    })
}

pub fn print_train(b: &TrainBench) {
    println!("device: {}", b.device);
    println!(
        "train {}x{}, {} Gaussians, SH {}, {} views, {} intersections: {:.1} ms/iteration wall (best {:.1}), {:.2} it/s, {:.2} submissions/iteration",
        b.width, b.height, b.gaussians, b.sh_degree, b.views, b.intersections, b.wall_ms, b.wall_ms_best, b.it_per_s, b.submissions_per_iteration
    );
    println!(
        "  GPU ms/iteration: forward {:.1}, loss {:.1}, backward {:.1} ({:.2}x forward{}), Adam {:.1}{}; total {:.1}",
        b.forward_ms,
        b.loss_ms,
        b.backward_ms,
        b.backward_ms / b.forward_ms.max(1e-9),
        if b.adam_fused { "; Adam fused into its reduce" } else { "" },
        b.adam_ms,
        if b.adam_fused { " (the gate)" } else { "" },
        b.gpu_ms
    );
    println!(
        "  device memory: peak {:.1} MiB ({:.0} bytes per Gaussian, images and frames included); {} bytes per intersection of frame capacity",
        b.peak_memory_mib,
        b.peak_memory_mib * 1048576.0 / b.gaussians.max(1) as f64,
        b.bytes_per_intersection
    );
    if let Some(s) = b.brush_lavapipe_s {
        println!(
            "  Brush, as timed on the reference lavapipe machine (not here): {:.0} ms/iteration; ratio {:.2}x (goal 10x: {:.0} ms) holds only if this machine is as fast as that one",
            s * 1e3,
            s * 1e3 / b.wall_ms,
            s * 1e2
        );
    }
    for k in &b.kernels {
        println!("  {:24} {:9.3} ms  ({} calls)", k.name, k.ms, k.calls);
    }
}

/// A timed run's settings on `points` fixed Gaussians: the quick preset,
/// Stage I only, black background, no tests or checkpoints, densification
/// off (the count stays fixed, as in Brush's timing). `init_points` (random
/// initialisation) is unused where the points are given, but may not
/// exceed `max_gaussians`.
pub fn bench_config(points: u32) -> TrainConfig {
    TrainConfig {
        background: "black".into(),
        densify_until: 0,
        max_gaussians: points,
        init_points: points.max(1),
        test_interval: 0,
        checkpoint_interval: 0,
        stages: "I".into(),
        ..TrainConfig::quick()
    }
}
