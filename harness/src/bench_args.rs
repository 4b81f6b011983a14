//! The `tgs bench` subcommands and their options (the command line's
//! part; the benchmarks themselves are the library's `bench*` modules).

use anyhow::{bail, Context as _, Result};
use std::path::PathBuf;
use std::sync::Arc;
use tgs_engine::Context;
use tgs_pipelines::SortConfig;

#[derive(clap::Subcommand)]
pub(crate) enum Bench {
    /// Radix sort of N random key-value pairs.
    Sort {
        #[arg(long, default_value_t = 1 << 20)]
        n: u32,
        /// Significant key bits to sort (1..=32).
        #[arg(long, default_value_t = 32)]
        bits: u32,
        /// Timed repetitions (after one warm-up).
        #[arg(long, default_value_t = 5)]
        reps: u32,
        /// Override the digit width (4 or 8); with --wg and --kpt.
        #[arg(long)]
        radix_bits: Option<u32>,
        #[arg(long)]
        wg: Option<u32>,
        #[arg(long)]
        kpt: Option<u32>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// 2DGS rasterizer forward + backward on a synthetic scene of N Gaussians.
    Raster {
        #[arg(long, default_value_t = 100_000)]
        n: u32,
        #[arg(long, default_value_t = 256)]
        width: u32,
        #[arg(long, default_value_t = 256)]
        height: u32,
        #[arg(long, default_value_t = 3)]
        reps: u32,
        #[arg(long)]
        json: bool,
    },
    /// Whole training iterations (forward, loss, backward, Adam; count frozen)
    /// on Brush's workload: the spheres scene, 20 views, SH 3.
    Train {
        /// Image size (square).
        #[arg(long, default_value_t = 128)]
        res: u32,
        /// Gaussians (initial points on the spheres) [default: 10000, or
        /// 1000000 with --real-scale].
        #[arg(long)]
        points: Option<u32>,
        /// Training views (they hold images only; the work per iteration
        /// does not depend on their number).
        #[arg(long, default_value_t = 20)]
        views: u32,
        /// The size users train instead of --res/--views: a Mip-NeRF 360
        /// frame (1237x822), a million Gaussians (unless --points), 8 views.
        #[arg(long, conflicts_with_all = ["res", "views"])]
        real_scale: bool,
        /// A trained model instead of the spheres: Stage I iterations on
        /// the scattering set of this `tgs train` run directory (its Stage I
        /// checkpoint), its dataset and settings, the Gaussian count fixed.
        #[arg(long, value_name = "RUN", conflicts_with_all = ["res", "points", "views", "real_scale"])]
        from: Option<PathBuf>,
        /// Timed iterations (after the warm-up).
        #[arg(long, default_value_t = 20)]
        iterations: u32,
        #[arg(long, default_value_t = 3)]
        warmup: u32,
        /// Step Adam in its own pass after the backward instead of fused
        /// into the per-Gaussian reduce (the same parameters; for
        /// comparison). Default: as training does, fused on CPU devices only.
        #[arg(long)]
        separate_adam: bool,
        /// Fuse Adam into the per-Gaussian reduce where the device can.
        #[arg(long, conflicts_with = "separate_adam")]
        fused_adam: bool,
        /// Stage III iterations instead of Stage I's on this workload: the
        /// scattering colour and a reflection set of every tenth Gaussian
        /// lit by the light field of this preset (small or paper).
        #[arg(long, value_name = "NETWORK", conflicts_with_all = ["from", "separate_adam", "fused_adam"])]
        light_field: Option<String>,
        #[arg(long)]
        json: bool,
    },
    /// The light-field MLP (encode, forward, backward, reduce) on N random samples.
    Mlp {
        /// Network preset: paper (8 x 256, L 12) or small.
        #[arg(long, default_value = "paper")]
        preset: String,
        /// Override the preset's hidden layers, width, skip layer or Fourier levels.
        #[arg(long)]
        depth: Option<u32>,
        #[arg(long)]
        width: Option<u32>,
        #[arg(long)]
        skip: Option<u32>,
        #[arg(long)]
        levels: Option<u32>,
        #[arg(long, default_value_t = 4096)]
        n: u32,
        #[arg(long, default_value_t = 3)]
        reps: u32,
        /// The GEMM kernel: auto (rows on CPU devices, tiled on GPUs;
        /// TGS_MLP_GEMM overrides), tiled, rows or fused (the forward and
        /// the input gradients each one kernel, the weight gradients tiled).
        #[arg(long, default_value = "auto")]
        gemm: String,
        #[arg(long)]
        json: bool,
    },
    /// Iterations of Stage I, II and III on a built-in scene: GPU ms per
    /// kernel per stage, wall ms per iteration, memory.
    Stages {
        /// Built-in scene (tgs scene list).
        #[arg(long, default_value = "glass")]
        scene: String,
        /// Untimed training iterations of Stages I and II before timing.
        #[arg(long, default_value_t = 300)]
        train: u32,
        /// Untimed training iterations of Stage III before timing.
        #[arg(long, default_value_t = 50)]
        train_light_field: u32,
        #[arg(long, default_value_t = 3)]
        warmup: u32,
        /// Timed iterations per stage.
        #[arg(long, default_value_t = 10)]
        iterations: u32,
        /// Stage III network preset: small or paper.
        #[arg(long, default_value = "small")]
        mlp: String,
        /// A training setting as KEY=VALUE, as `tgs train --set` takes it
        /// (repeatable), over the quick preset: for example
        /// reflection.dataset_masks=false to time Stage II and III seeded
        /// from the residual. The iteration counts, the densification's end,
        /// the stages and the network are the bench's own (refused here).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        #[arg(long)]
        json: bool,
    },
    /// LPIPS (AlexNet v0.1, on the CPU) of two SIZE x SIZE images: seconds
    /// per image pair and GFLOP/s.
    Lpips {
        #[arg(long, default_value_t = 800)]
        size: u32,
        #[arg(long, default_value_t = 3)]
        reps: u32,
        #[arg(long)]
        json: bool,
    },
    /// The viewer's frame without a window: a run's final image on an
    /// orbit, rendered and packed as `tgs view` draws it (for machines with
    /// no display; `perf/view/bench.sh` times the window).
    View {
        /// A `tgs train` run directory.
        run: PathBuf,
        /// Frame size WIDTHxHEIGHT.
        #[arg(long, default_value = "800x600", value_parser = crate::parse_size)]
        size: (u32, u32),
        #[arg(long, default_value_t = 120)]
        frames: u32,
        /// GPU time per kernel scope, ms a frame (timestamp queries).
        #[arg(long)]
        profile: bool,
        #[arg(long)]
        json: bool,
    },
    /// Exclusive prefix sum of N u32.
    Scan {
        #[arg(long, default_value_t = 1 << 20)]
        n: u32,
        #[arg(long, default_value_t = 5)]
        reps: u32,
        #[arg(long)]
        json: bool,
    },
}

/// A benchmark's result as JSON, or printed for people.
fn show<T: serde::Serialize>(b: &T, json: bool, print: impl FnOnce(&T)) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(b)?);
    } else {
        print(b);
    }
    Ok(())
}

impl Bench {
    /// Run the benchmark on `ctx` (all but `lpips`, which needs no device).
    pub(crate) fn run(&self, ctx: &Arc<Context>) -> Result<()> {
        match self {
            Bench::Sort { n, bits, reps, radix_bits, wg, kpt, json } => {
                let cfg = if radix_bits.is_some() || wg.is_some() || kpt.is_some() {
                    let d = SortConfig::for_device(ctx.caps());
                    Some(SortConfig { radix_bits: radix_bits.unwrap_or(d.radix_bits), wg: wg.unwrap_or(d.wg), kpt: kpt.unwrap_or(d.kpt) })
                } else {
                    None
                };
                let b = tgs::bench::sort(ctx, *n, *bits, *reps, cfg)?;
                show(&b, *json, |b| {
                    println!("device: {}", b.device);
                    tgs::bench::print_sort(b);
                })?;
                if !b.verified {
                    bail!("the GPU sort produced unsorted output");
                }
                Ok(())
            }
            Bench::Raster { n, width, height, reps, json } => show(&tgs::bench_raster::raster(ctx, *n, *width, *height, *reps)?, *json, tgs::bench_raster::print_raster),
            Bench::Train { .. } => self.train(ctx),
            Bench::Mlp { preset, depth, width, skip, levels, n, reps, gemm, json } => {
                let gemm = if gemm == "auto" { None } else { Some(tgs_pipelines::mlp::Gemm::parse(gemm).context("--gemm (auto, tiled, rows)")?) };
                let mut shape = tgs_pipelines::MlpShape::preset(preset)?;
                shape.depth = depth.unwrap_or(shape.depth);
                shape.width = width.unwrap_or(shape.width);
                shape.skip = skip.unwrap_or(shape.skip);
                if let Some(l) = levels {
                    shape.levels_x = *l;
                    shape.levels_w = *l;
                }
                show(&tgs::bench_mlp::mlp(ctx, shape, *n, *reps, gemm)?, *json, |b| {
                    println!("device: {}", b.device);
                    tgs::bench_mlp::print_mlp(b);
                })
            }
            Bench::Stages { scene, train, train_light_field, warmup, iterations, mlp, set, json } => {
                let spec = tgs::bench_stages::StagesSpec {
                    scene: scene.clone(),
                    train: *train,
                    train_light_field: *train_light_field,
                    warmup: *warmup,
                    iterations: *iterations,
                    mlp: mlp.clone(),
                    set: set.clone(),
                };
                show(&tgs::bench_stages::stages(ctx, &spec)?, *json, tgs::bench_stages::print_stages)
            }
            Bench::View { run, size, frames, profile, json } => show(&tgs::bench_view::view(ctx, run, (size.0, size.1), *frames, *profile)?, *json, tgs::bench_view::print_view),
            Bench::Lpips { size, reps, json } => tgs::bench::lpips(*size, *reps, *json),
            Bench::Scan { n, reps, json } => show(&tgs::bench::scan(ctx, *n, *reps)?, *json, |b| {
                println!("device: {}", b.device);
                tgs::bench::print_scan(b);
            }),
        }
    }

    /// `tgs bench train`: a Stage I workload, a run's state, or the light field.
    fn train(&self, ctx: &Arc<Context>) -> Result<()> {
        let Bench::Train { res, points, views, real_scale, from, iterations, warmup, separate_adam, fused_adam, light_field, json } = self else {
            unreachable!("called for bench train")
        };
        use tgs::bench_train::Workload;
        let w = if *real_scale {
            Workload { points: points.unwrap_or(Workload::REAL_SCALE.points), ..Workload::REAL_SCALE }
        } else {
            Workload { views: *views, ..Workload::square(*res, points.unwrap_or(10_000)) }
        };
        if let Some(net) = light_field {
            let net = tgs::train::stages::light_field::settings::LightPreset::parse(net).map_err(|e| anyhow::anyhow!("--light-field: {e}"))?;
            return show(&tgs::bench_light_field::light_field(ctx, w, *warmup, *iterations, net)?, *json, tgs::bench_light_field::print_light_field);
        }
        let fuse = if *separate_adam {
            Some(false)
        } else if *fused_adam {
            Some(true)
        } else {
            None
        };
        let b = match from {
            Some(run) => tgs::bench_train::train_from(ctx, run, *warmup, *iterations, fuse)?,
            None => tgs::bench_train::train(ctx, w, *warmup, *iterations, fuse)?,
        };
        show(&b, *json, tgs::bench_train::print_train)
    }
}
