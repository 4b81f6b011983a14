//! The `tgs bench` subcommands and their options (the command line's
//! part; the benchmarks themselves are the library's `bench*` modules).

use std::path::PathBuf;

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
