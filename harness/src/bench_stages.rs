//! Benchmark of all three training stages on a built-in scene: GPU ms per
//! kernel per stage (timestamp queries), wall ms per iteration, device
//! memory, device and driver. Shared by `tgs bench stages` and
//! `cargo bench --bench stages`.
//!
//! The trainer runs the default schedule I → II → III on the scene with
//! short stages: each stage first trains `train` iterations untimed
//! (`train_light_field` for Stage III; Stage I densifies during them, when
//! they reach the preset's densify_from, and then stops, so the Gaussian
//! count is fixed while timing), then `warmup` iterations, then `iterations` timed by wall
//! clock, then up to 5 profiled ones. The stage switches (the residual of
//! every training view and the seeding; the light-field model) are timed
//! on their own. The per-iteration cost depends on the state training has
//! reached (Gaussian counts, the fraction of pixels Φ evaluates), so both
//! are reported beside the times.

use crate::bench::{average, nested_scope, KernelTime};
use crate::train::stages::light_field;
use crate::train::{Stage, TrainConfig, Trainer};
use anyhow::{ensure, Context as _, Result};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::Context;

/// What to run.
#[derive(Clone, Debug)]
pub struct StagesSpec {
    /// A built-in scene (`tgs scene list`).
    pub scene: String,
    /// Untimed iterations of Stages I and II before timing.
    pub train: u32,
    /// Untimed iterations of Stage III before timing (its iterations cost
    /// up to 10x Stage I's with the paper network on a CPU driver).
    pub train_light_field: u32,
    pub warmup: u32,
    /// Timed iterations per stage.
    pub iterations: u32,
    /// Stage III network preset (paper or small).
    pub mlp: String,
    /// Training settings as KEY=VALUE over the quick preset (`tgs train
    /// --set`'s syntax), except those in [`BENCH_KEYS`].
    pub set: Vec<String>,
}

/// The settings the bench sets itself from its own options: a `--set` of
/// one of them is refused rather than silently overwritten.
pub const BENCH_KEYS: [&str; 8] =
    ["iterations", "densify_until", "test_interval", "checkpoint_interval", "stages", "reflection.iterations", "light_field.iterations", "light_field.preset"];

#[derive(Clone, Debug, Serialize)]
pub struct StageTimes {
    pub stage: String,
    pub scattering_gaussians: u32,
    /// Reflection-set Gaussians (Stages II and III).
    pub reflection_gaussians: Option<u32>,
    /// Fraction of pixels Φ was evaluated on (Stage III, profiled iterations).
    pub phi_fraction: Option<f64>,
    pub wall_ms: f64,
    pub wall_ms_best: f64,
    pub it_per_s: f64,
    /// Sum of the top-level scopes (nested sort/scan passes not counted twice).
    pub gpu_ms: f64,
    /// Every timed scope, ms per iteration, in order of first appearance.
    pub kernels: Vec<KernelTime>,
    /// Wall ms of the switch into this stage (Stages II and III).
    pub switch_ms: Option<f64>,
    /// Device memory held by the engine at the end of the stage, and the
    /// most held at once during it, MiB.
    pub memory_mib: f64,
    pub peak_memory_mib: f64,
}

#[derive(Clone, Debug, Serialize)]
pub struct StagesBench {
    pub device: String,
    pub scene: String,
    pub width: u32,
    pub height: u32,
    pub train_views: u32,
    pub mlp: String,
    /// The kernel Stage III's MLP runs on (`TGS_MLP_GEMM` chooses).
    pub mlp_kernel: String,
    pub train: u32,
    pub train_light_field: u32,
    pub warmup: u32,
    pub iterations: u32,
    /// The `--set` settings the run took, as given.
    pub set: Vec<String>,
    pub stages: Vec<StageTimes>,
    /// Stages the scene did not call for (Stage II skipped by the residual test).
    pub skipped: Vec<String>,
}

fn mib(bytes: u64) -> f64 {
    bytes as f64 / 1048576.0
}

pub fn stages(ctx: &Arc<Context>, spec: &StagesSpec) -> Result<StagesBench> {
    ensure!(spec.iterations > 0, "--iterations must be at least 1");
    let dir = std::env::temp_dir().join(format!("tgs-bench-scene-{}-{}", spec.scene, std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    crate::scene::make_named(&spec.scene, &dir, |_, _| {})?;
    let result = run(ctx, spec, &dir);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn run(ctx: &Arc<Context>, spec: &StagesSpec, dir: &std::path::Path) -> Result<StagesBench> {
    let (cfg, profiled) = bench_config(spec)?;
    let data = crate::train::run::load_dataset(dir, &cfg)?;
    let cam = data.train.first().context("the scene has no training views")?.camera;
    let mut tr = Trainer::new(ctx, cfg, &data)?;
    let mut out = StagesBench {
        device: ctx.caps().describe(),
        scene: spec.scene.clone(),
        width: cam.width,
        height: cam.height,
        train_views: data.train.len() as u32,
        mlp: spec.mlp.clone(),
        mlp_kernel: tgs_pipelines::mlp::Gemm::for_device(ctx)?.name().into(),
        train: spec.train,
        train_light_field: spec.train_light_field,
        warmup: spec.warmup,
        iterations: spec.iterations,
        set: spec.set.clone(),
        stages: Vec::new(),
        skipped: Vec::new(),
    };
    let all = Stage::all();
    for (i, &stage) in all.iter().enumerate() {
        ctx.reset_peak_memory();
        let t = Instant::now();
        let switch_ms = if stage == Stage::SCATTERING {
            None
        } else {
            if tr.next_begins().map(|k| k.stage()) != Some(stage) {
                break;
            }
            if !tr.begin_next(None, true)?.runs {
                out.skipped.extend(all[i..].iter().map(|s| s.name().to_string()));
                break;
            }
            Some(t.elapsed().as_secs_f64() * 1e3)
        };
        out.stages.push(time_stage(ctx, &mut tr, spec, stage, profiled, switch_ms)?);
    }
    Ok(out)
}

/// The quick preset with the bench's lengths: every stage `train` (Stage
/// III `train_light_field`) untimed iterations, then the warm-up, timed and
/// profiled ones; and how many are profiled.
fn bench_config(spec: &StagesSpec) -> Result<(TrainConfig, u32)> {
    let mut cfg = TrainConfig::quick();
    for kv in &spec.set {
        let key = kv.split_once('=').map(|(k, _)| k.trim()).unwrap_or(kv.as_str());
        ensure!(!BENCH_KEYS.contains(&key), "--set '{kv}': the bench sets {key} itself (see --train, --train-light-field, --iterations and --mlp)");
        cfg.set(kv)?;
    }
    let profiled = spec.iterations.clamp(1, 5);
    let timed = spec.warmup + spec.iterations + profiled;
    let per_stage = spec.train + timed;
    cfg.iterations = per_stage;
    cfg.densify_until = spec.train.min(cfg.densify_until);
    cfg.test_interval = 0;
    cfg.checkpoint_interval = 0;
    cfg.stages = "I,II,III".into();
    cfg.reflection.iterations = per_stage;
    cfg.light_field.iterations = spec.train_light_field + timed;
    cfg.light_field.preset = crate::train::stages::light_field::settings::LightPreset::parse(&spec.mlp).map_err(anyhow::Error::msg)?;
    Ok((cfg, profiled))
}

/// One stage begun: its untimed and warm-up iterations, then the timed
/// ones (wall) and the profiled ones (GPU timestamps per kernel).
fn time_stage(ctx: &Arc<Context>, tr: &mut Trainer, spec: &StagesSpec, stage: Stage, profiled: u32, switch_ms: Option<f64>) -> Result<StageTimes> {
    let untimed = if stage == light_field::stage::STAGE { spec.train_light_field } else { spec.train };
    for _ in 0..untimed + spec.warmup {
        tr.step(false)?;
    }
    let mut walls = Vec::new();
    for _ in 0..spec.iterations {
        let t = Instant::now();
        tr.step(false)?;
        walls.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let mut all = Vec::new();
    let mut phi = Vec::new();
    for _ in 0..profiled {
        let r = tr.step(true)?;
        ensure!(r.stage == stage, "the schedule is at Stage {}, not {}", r.stage.name(), stage.name());
        all.push(r.timings);
        if let Some(f) = tr.later.as_mut().and_then(|m| m.take_coverage()) {
            phi.push(f);
        }
    }
    let kernels = average(all);
    let wall_ms = walls.iter().sum::<f64>() / walls.len() as f64;
    let reflection_gaussians = if stage == Stage::SCATTERING { None } else { tr.later.as_ref().map(|m| m.set().len()) };
    let mem = ctx.memory_use();
    Ok(StageTimes {
        stage: stage.name().into(),
        scattering_gaussians: tr.scattering.set.len(),
        reflection_gaussians,
        phi_fraction: (!phi.is_empty()).then(|| phi.iter().sum::<f64>() / phi.len() as f64),
        wall_ms,
        wall_ms_best: walls.iter().copied().fold(f64::INFINITY, f64::min),
        it_per_s: 1e3 / wall_ms,
        gpu_ms: kernels.iter().filter(|k| !nested_scope(&k.name)).map(|k| k.ms).sum(),
        kernels,
        switch_ms,
        memory_mib: mib(mem.live_bytes),
        peak_memory_mib: mib(mem.peak_bytes),
    })
}

pub fn print_stages(b: &StagesBench) {
    println!("device: {}", b.device);
    println!(
        "stages on '{}' ({}x{}, {} training views), Stage III network '{}' on the {} kernel: per stage {} untimed ({} in Stage III), {} warm-up, {} timed iterations",
        b.scene, b.width, b.height, b.train_views, b.mlp, b.mlp_kernel, b.train, b.train_light_field, b.warmup, b.iterations
    );
    if !b.set.is_empty() {
        println!("settings over the quick preset: {}", b.set.join(", "));
    }
    for s in &b.stages {
        let refl = s.reflection_gaussians.map(|n| format!(", {n} reflection")).unwrap_or_default();
        let phi = s.phi_fraction.map(|f| format!(", Φ on {:.1}% of pixels", 100.0 * f)).unwrap_or_default();
        let switch = s.switch_ms.map(|m| format!("; switch into it {m:.0} ms")).unwrap_or_default();
        println!(
            "Stage {}: {:.1} ms/iteration wall (best {:.1}), {:.2} it/s; GPU {:.1} ms; {} scattering Gaussians{refl}{phi}; memory {:.1} MiB (peak {:.1}){switch}",
            s.stage, s.wall_ms, s.wall_ms_best, s.it_per_s, s.gpu_ms, s.scattering_gaussians, s.memory_mib, s.peak_memory_mib
        );
        for k in &s.kernels {
            let indent = if nested_scope(&k.name) { "      " } else { "    " };
            println!("{indent}{:26} {:9.3} ms  ({} calls)", k.name, k.ms, k.calls);
        }
    }
    for s in &b.skipped {
        println!("Stage {s}: skipped (the scene's Stage I residual is below reflection.min_residual, or does not change with the view enough for reflection.min_view_dependence)");
    }
}
