//! Stage III iterations on `tgs bench train`'s workloads (`tgs bench train
//! --light-field`): the spheres scene as the scattering set (its colour
//! trains, as Stage III's default), every `REFLECTION_EVERY`-th of its
//! Gaussians as a reflection set (f0 and r at Stage II's starting values,
//! the geometry frozen), the light field with the quick preset's small
//! network (or the paper's) on every pixel whose R passes the threshold.
//! What a Stage III iteration costs at the size users train (a Mip-NeRF 360
//! frame: `--real-scale`), per kernel, with the Φ samples per view and the
//! peak device memory. The reflection set is not fitted to anything, so
//! only the costs mean something.

use crate::bench::{average, nested_scope, KernelTime};
use crate::bench_train::Workload;
use crate::scene::spheres::{self, SpheresSpec};
use crate::train::stages::light_field;
use crate::train::stages::light_field::model::LightFieldStepInput;
use crate::train::stages::light_field::settings::LightPreset;
use crate::train::{TrainConfig, Trainer};
use anyhow::{ensure, Result};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::Context;
use tgs_pipelines::{HostGaussians, TrainableSet};

/// One reflection Gaussian per this many scattering ones.
const REFLECTION_EVERY: usize = 10;

#[derive(Clone, Debug, Serialize)]
pub struct LightFieldBench {
    pub device: String,
    pub width: u32,
    pub height: u32,
    pub scattering_gaussians: u32,
    pub reflection_gaussians: u32,
    pub network: String,
    pub warmup: u32,
    pub iterations: u32,
    pub wall_ms: f64,
    pub wall_ms_best: f64,
    /// Sum of the top-level scopes of the profiled iterations.
    pub gpu_ms: f64,
    pub kernels: Vec<KernelTime>,
    /// Fraction of the pixels Φ ran on (profiled iterations).
    pub phi_fraction: Option<f64>,
    /// Samples the light field takes in one pass (its activations' block).
    pub mlp_block: u32,
    pub peak_memory_mib: f64,
}

/// Time `iterations` Stage III iterations (after `warmup`) on workload `w`
/// with the light field `network` (small or paper).
/// The warm-up visits every view at least once: training's iterations
/// after its first pass over the views render and differentiate each
/// view's colours from its kept blend weights
/// (`light_field.kept_binning_mib`), and those are what the timed ones
/// stand for.
pub fn light_field(ctx: &Arc<Context>, w: Workload, warmup: u32, iterations: u32, network: LightPreset) -> Result<LightFieldBench> {
    ensure!(iterations > 0, "--iterations must be at least 1");
    let warmup = warmup.max(w.views);
    let spec = SpheresSpec { width: w.width, height: w.height, points: w.points, train: w.views, ..SpheresSpec::NAMED[0].1 };
    let data = spheres::dataset(&spec)?;
    let mut cfg = crate::bench_train::bench_config(w.points);
    cfg.light_field.preset = network;
    let profiled = iterations.clamp(1, 3);
    cfg.light_field.iterations = warmup.saturating_add(iterations).saturating_add(profiled);
    ctx.reset_peak_memory();
    let mut tr = Trainer::new(ctx, cfg.clone(), &data)?;
    let refl = reflection_set(&tr, &cfg)?;
    let reflection_gaussians = refl.len() as u32;
    let mut model = light_field::stage::begin(&cfg, ctx, TrainableSet::new(ctx, &refl)?)?;
    let sh = cfg.sh_degree_at(cfg.iterations);
    let mut it = 0u32;
    let mut step = |tr: &mut Trainer, model: &mut light_field::model::LightFieldModel, profile: bool| -> Result<Vec<tgs_engine::Timing>> {
        let view = it as usize % tr.views.cameras.len();
        it += 1;
        let input = LightFieldStepInput {
            iteration: it,
            global_iteration: cfg.iterations + it,
            camera: &tr.views.cameras[view],
            keep: light_field::KeepAs { view: view as u32, budget_mib: cfg.light_field.kept_binning_mib },
            target: &tr.views.targets[view],
            scat: None,
            sh_degree: sh,
            background: tr.views.background,
            lr_means: cfg.lr_means_final * tr.views.extent,
            profile,
        };
        Ok(model.step(&cfg, &mut tr.scattering, &input)?.timings)
    };
    for _ in 0..warmup {
        step(&mut tr, &mut model, false)?;
    }
    let mut walls = Vec::new();
    for _ in 0..iterations {
        let t = Instant::now();
        step(&mut tr, &mut model, false)?;
        walls.push(t.elapsed().as_secs_f64() * 1e3);
    }
    model.take_coverage();
    let mut all = Vec::new();
    for _ in 0..profiled {
        all.push(step(&mut tr, &mut model, true)?);
    }
    let kernels = average(all);
    Ok(LightFieldBench {
        device: ctx.caps().describe(),
        width: w.width,
        height: w.height,
        scattering_gaussians: tr.scattering.set.len(),
        reflection_gaussians,
        network: network.name().to_string(),
        warmup,
        iterations,
        wall_ms: walls.iter().sum::<f64>() / walls.len() as f64,
        wall_ms_best: walls.iter().copied().fold(f64::INFINITY, f64::min),
        gpu_ms: kernels.iter().filter(|k| !nested_scope(&k.name)).map(|k| k.ms).sum(),
        kernels,
        phi_fraction: model.take_coverage(),
        mlp_block: model.mlp_block(),
        peak_memory_mib: ctx.memory_use().peak_bytes as f64 / 1048576.0,
    })
}

/// The reflection set the bench trains: every `REFLECTION_EVERY`-th
/// Gaussian of the scattering set, with the initial material.
fn reflection_set(tr: &Trainer, cfg: &TrainConfig) -> Result<HostGaussians> {
    let scat = tr.scattering.set.params.download()?;
    let mut refl = HostGaussians::new(tgs_pipelines::reflection::MATERIAL, 1);
    let logit = |p: f32| (p / (1.0 - p)).ln();
    let (f0, r) = (logit(cfg.reflection.f0_init), logit(cfg.reflection.r_init));
    for i in (0..scat.len()).step_by(REFLECTION_EVERY) {
        let g = |v: &[f32], k: usize| -> Vec<f32> { v[k * i..k * (i + 1)].to_vec() };
        refl.push(g(&scat.means, 3).try_into().unwrap(), g(&scat.log_scales, 2).try_into().unwrap(), g(&scat.quats, 4).try_into().unwrap(), scat.opacity[i], &[f0, f0, f0, r]);
    }
    Ok(refl)
}

pub fn print_light_field(b: &LightFieldBench) {
    println!("device: {}", b.device);
    println!(
        "Stage III {}x{}, {} scattering and {} reflection Gaussians, {} light field: {:.1} ms/iteration wall (best {:.1}); GPU {:.1} ms (after {} warm-up iterations: every view binned once)",
        b.width, b.height, b.scattering_gaussians, b.reflection_gaussians, b.network, b.wall_ms, b.wall_ms_best, b.gpu_ms, b.warmup
    );
    println!(
        "  Φ on {} of the pixels, in blocks of {} samples; device memory: peak {:.1} MiB",
        b.phi_fraction.map(|f| format!("{:.1}%", 100.0 * f)).unwrap_or_else(|| "none".into()),
        b.mlp_block,
        b.peak_memory_mib
    );
    for k in &b.kernels {
        println!("  {:26} {:10.3} ms  ({} calls)", k.name, k.ms, k.calls);
    }
}
