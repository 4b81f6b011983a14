use anyhow::Result;
use clap::{Parser, Subcommand};
use tgs_engine::{Context, ContextOptions, DeviceSelector};
use tgs_pipelines::SortConfig;

#[derive(Parser)]
#[command(name = "tgs", version, about = "TransmissiveGS on Vulkan compute")]
struct Cli {
    /// Vulkan device: index or name substring (see `tgs devices`).
    #[arg(long, global = true, env = "TGS_DEVICE")]
    device: Option<String>,
    /// Enable the Khronos validation layer (slow).
    #[arg(long, global = true)]
    validate: bool,
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// List Vulkan devices with subgroup size, limits and driver.
    Devices {
        #[arg(long)]
        json: bool,
    },
    /// Time kernels with GPU timestamps.
    Bench {
        #[command(subcommand)]
        what: Bench,
    },
}

#[derive(Subcommand)]
enum Bench {
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

fn context(cli: &Cli) -> Result<std::sync::Arc<Context>> {
    Context::new(&ContextOptions {
        device: DeviceSelector::from_arg_or_env(cli.device.as_deref()),
        validation: Some(cli.validate),
    })
}

fn run(cli: Cli) -> Result<()> {
    match &cli.cmd {
        Cmd::Devices { json } => tgs::devices::run(*json),
        Cmd::Bench { what } => {
            let ctx = context(&cli)?;
            match what {
                Bench::Sort { n, bits, reps, radix_bits, wg, kpt, json } => {
                    let cfg = if radix_bits.is_some() || wg.is_some() || kpt.is_some() {
                        let d = SortConfig::for_device(ctx.caps());
                        Some(SortConfig {
                            radix_bits: radix_bits.unwrap_or(d.radix_bits),
                            wg: wg.unwrap_or(d.wg),
                            kpt: kpt.unwrap_or(d.kpt),
                        })
                    } else {
                        None
                    };
                    let b = tgs::bench::sort(&ctx, *n, *bits, *reps, cfg)?;
                    if *json {
                        println!("{}", serde_json::to_string_pretty(&b)?);
                    } else {
                        println!("device: {}", b.device);
                        tgs::bench::print_sort(&b);
                    }
                    if !b.verified {
                        anyhow::bail!("the GPU sort produced unsorted output");
                    }
                }
                Bench::Raster { n, width, height, reps, json } => {
                    let b = tgs::bench_raster::raster(&ctx, *n, *width, *height, *reps)?;
                    if *json {
                        println!("{}", serde_json::to_string_pretty(&b)?);
                    } else {
                        tgs::bench_raster::print_raster(&b);
                    }
                }
                Bench::Scan { n, reps, json } => {
                    let b = tgs::bench::scan(&ctx, *n, *reps)?;
                    if *json {
                        println!("{}", serde_json::to_string_pretty(&b)?);
                    } else {
                        println!("device: {}", b.device);
                        tgs::bench::print_scan(&b);
                    }
                }
            }
            Ok(())
        }
    }
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("tgs: error: {e:#}");
        std::process::exit(1);
    }
}
