use anyhow::{Context as _, Result};
use clap::{Parser, Subcommand};
use std::path::PathBuf;
use tgs::train::run::TrainArgs;
use tgs_engine::{Context, ContextOptions, DeviceSelector};

mod bench_args;
use bench_args::Bench;

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
    /// Train a TransmissiveGS scene (Stages I, II and III, or those --stages names) on a dataset directory
    /// (Blender layout or COLMAP); without one, on the built-in scene.
    Train {
        /// Dataset directory (transforms_train.json or sparse/); default: the built-in scene, written to OUT/scene.
        dataset: Option<PathBuf>,
        /// Run directory: checkpoint, log, outputs.
        #[arg(long, default_value = "runs/glass")]
        out: PathBuf,
        /// Settings preset: quick (the default) or paper. With --resume, the
        /// run's saved settings are used and only iterations, test_interval
        /// and checkpoint_interval may change.
        #[arg(long)]
        preset: Option<String>,
        /// TOML file of settings (applied after the preset).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Any setting as KEY=VALUE (repeatable; applied after --config). See config.toml in a run directory
        /// for the keys. A key that a flag also sets (--iterations, --stages, --downscale, --background) is
        /// refused when both are given.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        #[arg(long)]
        iterations: Option<u32>,
        #[arg(long)]
        downscale: Option<u32>,
        /// Background: white, black or r,g,b.
        #[arg(long)]
        background: Option<String>,
        /// Continue from OUT/checkpoint.bin with the run's saved settings and
        /// dataset (options that would change them are refused, except
        /// --iterations and --set test_interval / checkpoint_interval).
        #[arg(long)]
        resume: bool,
        /// Stages to run: I, I,II or I,II,III (the default); with --from,
        /// the stages after Stage I (II or II,III).
        #[arg(long)]
        stages: Option<String>,
        /// Start Stage II (and III) from the finished Stage I of the run
        /// directory RUN (its checkpoint), in a new --out, without training
        /// Stage I again.
        #[arg(long, value_name = "RUN")]
        from: Option<PathBuf>,
        /// Time every kernel of every iteration (GPU timestamps) into metrics.json.
        #[arg(long)]
        profile: bool,
        #[arg(long)]
        quiet: bool,
        /// Show the model in a window while it trains (`tgs view`'s window;
        /// the training is the same as without it; closing it leaves the training running).
        #[arg(long)]
        view: bool,
        /// With --view: the fewest milliseconds between the models the window is sent (at least 50;
        /// longer where drawing one takes more than a twentieth of that).
        #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(u64).range(50..=3_600_000))]
        view_every: u64,
        /// With --view: replay a `tgs view --script` file in the window (tests).
        #[arg(long, requires = "view")]
        view_script: Option<PathBuf>,
    },
    /// PSNR, SSIM and normal MAE of a run's checkpoint on its test views.
    Eval {
        run: PathBuf,
        /// Also write the renders here.
        #[arg(long)]
        out: Option<PathBuf>,
        /// KEY=VALUE: an output-only setting to evaluate with (reflection.normal_min_r,
        /// reflection.residual_normal_min_r, reflection.normal_min_alpha); the run itself is not changed (repeatable).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
    },
    /// Render a run's checkpoint along test, train or orbit cameras.
    Render {
        run: PathBuf,
        #[arg(long, default_value = "test")]
        cameras: String,
        /// Orbit frames (1 to 100,000).
        #[arg(long, default_value_t = 60, value_parser = clap::value_parser!(u32).range(1..=100_000))]
        frames: u32,
        /// Output directory (default RUN/renders/CAMERAS).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Look at a run in a window: orbit (left drag), pan (right drag), zoom
    /// (wheel), fly (W A S D Q E); N/P step through the dataset's cameras,
    /// L the layers, C the Stage I/II/III checkpoints, O a screenshot, H the keys.
    View {
        run: PathBuf,
        /// Window size WxH (default: the camera's, scaled up to at least 400 wide).
        #[arg(long, value_parser = parse_size)]
        size: Option<(u32, u32)>,
        /// Start at this dataset camera (0-based).
        #[arg(long, default_value_t = 0)]
        camera: usize,
        /// Start on the training cameras instead of the test cameras.
        #[arg(long)]
        train_cameras: bool,
        /// Replay the actions in FILE (key N, orbit DX DY, pan, zoom, resize W H,
        /// capture FILE, wait FRAMES, quit), then quit: tests and recordings.
        #[arg(long)]
        script: Option<PathBuf>,
        /// Directory for screenshots (default RUN/screenshots; never written over).
        #[arg(long)]
        shots: Option<PathBuf>,
        /// Marking the glass: how many outlined views may leave a point out
        /// and it still counts as glass (0: all must hold it; 1 forgives a
        /// view whose outline an occluder cut short).
        #[arg(long, default_value_t = 0)]
        mark_tolerance: usize,
        /// While the camera moves, draw frames smaller (and enlarged) where a
        /// full-size frame would fall below this rate; the full frame follows
        /// once it rests (0: always full size).
        #[arg(long, default_value_t = tgs::view::motion::DEFAULT_FPS)]
        motion_fps: f32,
    },
    /// Meshes of a run by TSDF fusion of rendered median depth over the
    /// training views, extracted by marching tetrahedra: mesh_scene.ply (the
    /// scattering set, vertex colours) and, after Stage II, mesh_glass.ply
    /// (the reflection set where it covers a pixel, weighted by its alpha).
    Mesh {
        run: PathBuf,
        /// Voxel size in world units (default: two pixels' footprint at the
        /// surfaces' median depth, at most --resolution voxels along the
        /// longest side of their box).
        #[arg(long)]
        voxel: Option<f32>,
        /// Most voxels along the box's longest side when --voxel is not given.
        #[arg(long, default_value_t = 512, value_parser = clap::value_parser!(u32).range(2..=4096))]
        resolution: u32,
        /// Truncation distance in world units (default: 4 voxels).
        #[arg(long)]
        trunc: Option<f32>,
        /// Depths past this are not fused (default: no limit).
        #[arg(long)]
        depth_max: Option<f32>,
        /// Largest voxel grid in MiB of device memory (20 bytes a voxel).
        #[arg(long, default_value_t = 2048)]
        max_mib: u64,
        /// Output directory (default: RUN).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Built-in procedural scenes.
    Scene {
        #[command(subcommand)]
        what: SceneCmd,
    },
    /// Train a grid of settings that trade accuracy for time: one row per
    /// run in OUT/sweep.csv (settings, wall time, GPU ms per iteration, test
    /// PSNR / SSIM / normal MAE / LPIPS per stage) and plots against wall time with
    /// the Pareto front. Run it again to resume.
    Sweep {
        /// Dataset directory; default: the built-in scene, written to OUT/scene.
        dataset: Option<PathBuf>,
        #[arg(long, required_unless_present = "print_grid")]
        out: Option<PathBuf>,
        /// Grid file (TOML: preset, mode, [base], [knobs]); default: the
        /// built-in grid (`tgs sweep --print-grid` shows it).
        #[arg(long)]
        grid: Option<PathBuf>,
        /// Print the built-in grid and exit.
        #[arg(long)]
        print_grid: bool,
        #[arg(long)]
        quiet: bool,
    },
    /// Time kernels with GPU timestamps.
    Bench {
        #[command(subcommand)]
        what: Bench,
    },
}

#[derive(Subcommand)]
enum SceneCmd {
    /// Write a built-in scene (glass, glass-tiny, diffuse, spheres-128, spheres-256) as
    /// a dataset into a new or empty directory.
    Make {
        name: String,
        #[arg(long)]
        out: PathBuf,
    },
    /// List the built-in scenes.
    List,
}

/// `WxH` (each 1 to 16384).
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("'{s}' is not a size WxH (e.g. 800x600)");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let p = |v: &str| v.trim().parse::<u32>().ok().filter(|n| (1..=16384).contains(n)).ok_or_else(bad);
    Ok((p(w)?, p(h)?))
}

fn context(cli: &Cli) -> Result<std::sync::Arc<Context>> {
    Context::new(&ContextOptions { device: DeviceSelector::from_arg_or_env(cli.device.as_deref()), validation: Some(cli.validate) })
}

fn run(cli: Cli) -> Result<()> {
    match &cli.cmd {
        Cmd::Devices { json } => tgs::devices::run(*json, &DeviceSelector::from_arg_or_env(cli.device.as_deref())),
        Cmd::Train { dataset, out, preset, config, set, iterations, downscale, background, resume, stages, from, profile, quiet, view, view_every, view_script } => {
            let args = TrainArgs {
                dataset: dataset.clone(),
                out: out.clone(),
                preset: preset.clone(),
                config: config.clone(),
                set: set.clone(),
                iterations: *iterations,
                downscale: *downscale,
                background: background.clone(),
                resume: *resume,
                stages: stages.clone(),
                from: from.clone(),
                profile: *profile,
                quiet: *quiet,
                live: None,
            };
            let o = if *view {
                let sel = DeviceSelector::from_arg_or_env(cli.device.as_deref());
                let v = tgs::view::ViewArgs {
                    run: out.clone(),
                    size: None,
                    camera: 0,
                    train: false,
                    script: view_script.clone(),
                    shots: None,
                    mark_tolerance: 0,
                    motion_fps: tgs::view::motion::DEFAULT_FPS,
                    device: sel.clone(),
                };
                let validate = cli.validate;
                tgs::view::train_live(&args, &v, std::time::Duration::from_millis(*view_every), move || Context::new(&ContextOptions { device: sel, validation: Some(validate) }))?
            } else {
                tgs::train::run::train(&context(&cli)?, &args)?
            };
            if o.interrupted {
                std::process::exit(130);
            }
            Ok(())
        }
        Cmd::Eval { run, out, set } => eval(&context(&cli)?, run, out.as_deref(), set),
        Cmd::Render { run, cameras, frames, out } => {
            let dir = out.clone().unwrap_or_else(|| run.join("renders").join(cameras));
            let n = tgs::render::render(&context(&cli)?, run, cameras, *frames, &dir)?;
            eprintln!("{n} views written to {}", dir.display());
            Ok(())
        }
        Cmd::Mesh { run, voxel, resolution, trunc, depth_max, max_mib, out } => {
            let args = tgs::mesh::MeshArgs {
                voxel: *voxel,
                resolution: *resolution,
                trunc: *trunc,
                depth_max: *depth_max,
                max_bytes: max_mib.saturating_mul(1 << 20),
                out: out.clone(),
                progress: true,
            };
            for r in tgs::mesh::mesh(&context(&cli)?, run, &args)? {
                eprintln!("{}: {} vertices, {} triangles", r.path.display(), r.mesh.positions.len(), r.mesh.triangles.len());
            }
            Ok(())
        }
        Cmd::View { run, size, camera, train_cameras, script, shots, mark_tolerance, motion_fps } => tgs::view::view(&tgs::view::ViewArgs {
            run: run.clone(),
            size: *size,
            camera: *camera,
            train: *train_cameras,
            script: script.clone(),
            shots: shots.clone(),
            mark_tolerance: *mark_tolerance,
            motion_fps: *motion_fps,
            device: DeviceSelector::from_arg_or_env(cli.device.as_deref()),
        }),
        Cmd::Scene { what } => scene(what),
        Cmd::Sweep { dataset, out, grid, print_grid, quiet } => {
            if *print_grid {
                print!("{}", tgs::sweep::DEFAULT_GRID.trim_start());
                return Ok(());
            }
            let out = out.as_ref().context("--out DIR is needed")?;
            sweep(&context(&cli)?, &tgs::sweep::SweepArgs { dataset: dataset.clone(), out: out.clone(), grid: grid.clone(), quiet: *quiet })
        }
        Cmd::Bench { what: Bench::Lpips { size, reps, json } } => tgs::bench::lpips(*size, *reps, *json),
        Cmd::Bench { what } => what.run(&context(&cli)?),
    }
}

/// `tgs eval RUN [--out DIR] [--set KEY=VALUE]`: the test metrics as JSON (renders into DIR).
fn eval(ctx: &std::sync::Arc<Context>, run: &std::path::Path, out: Option<&std::path::Path>, set: &[String]) -> Result<()> {
    let (mut tr, data) = tgs::train::run::open_run(ctx, run)?;
    tgs::train::run::set_output_settings(&mut tr, set).with_context(|| format!("tgs eval {}", run.display()))?;
    if data.test.is_empty() {
        anyhow::bail!("{}: the dataset has no test views", data.root.display());
    }
    let mut dir = match out {
        Some(d) => Some(tgs::outdir::OutDir::open(d, Some(&data.root))?),
        None => None,
    };
    // Only a writer locks: eval without --out reads the run.
    let _lock = match out {
        Some(d) => Some(tgs::lock::lock_output(d, run, "tgs eval", false)?),
        None => None,
    };
    let m = tgs::eval::evaluate(&mut tr, &data.test, dir.as_mut())?;
    println!("{}", serde_json::to_string_pretty(&m)?);
    Ok(())
}

/// `tgs scene list` and `tgs scene make NAME --out DIR`.
fn scene(what: &SceneCmd) -> Result<()> {
    match what {
        SceneCmd::List => {
            for line in tgs::scene::list() {
                println!("{line}");
            }
        }
        SceneCmd::Make { name, out } => {
            let bar = indicatif::ProgressBar::new(0);
            tgs::scene::make_named(name, out, |d, total| {
                bar.set_length(total as u64);
                bar.set_position(d as u64)
            })?;
            bar.finish_and_clear();
            eprintln!("scene '{name}' written to {}", out.display());
        }
    }
    Ok(())
}

/// `tgs sweep`: the runs, then their table with the Pareto front marked.
fn sweep(ctx: &std::sync::Arc<Context>, a: &tgs::sweep::SweepArgs) -> Result<()> {
    let o = tgs::sweep::sweep(ctx, a)?;
    if o.interrupted {
        eprintln!("sweep interrupted after {} new run(s); run the same command again to resume", o.trained);
        std::process::exit(130);
    }
    eprintln!("sweep: {} runs ({} trained now); {} and plots in {}", o.rows.len(), o.trained, a.out.join("sweep.csv").display(), a.out.display());
    let front = tgs::sweep::pareto(&o.rows, |r| r.psnr);
    println!("{:48} {:>9} {:>8} {:>8} {:>8} {:>9}  pareto", "run", "wall s", "PSNR", "SSIM", "LPIPS", "MAE °");
    for (i, r) in o.rows.iter().enumerate() {
        println!("{:48} {:9.1} {:8.3} {:8.4} {:8.4} {:9.2}  {}", r.name, r.wall_s, r.psnr, r.ssim, r.lpips, r.normal_mae_deg, if front.contains(&i) { "*" } else { "" });
    }
    Ok(())
}

fn main() {
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("tgs: error: {e:#}");
        std::process::exit(1);
    }
}
