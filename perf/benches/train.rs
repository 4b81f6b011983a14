//! `cargo bench --bench train`: whole training iterations (forward, loss,
//! backward, reduce, Adam; Gaussian count frozen) on Brush's workload, the
//! spheres scene: 10k Gaussians at 128² and 50k at 256², 20 views, SH 3.
//! Prints the device, wall and per-kernel GPU ms per iteration, and Brush's
//! time on the reference lavapipe machine; JSON to target/tgs-bench/train.json.

use serde_json::json;
use tgs_engine::{Context, ContextOptions, DeviceSelector};

fn main() -> anyhow::Result<()> {
    // `cargo bench -- NAME` runs only benches whose name contains NAME.
    if let Some(f) = std::env::args().skip(1).find(|a| !a.starts_with('-')) {
        if !"train".contains(f.as_str()) {
            return Ok(());
        }
    }
    let ctx = Context::new(&ContextOptions { device: DeviceSelector::from_arg_or_env(None), validation: Some(false) })?;
    println!("device: {}", ctx.caps().describe());
    let cpu = ctx.caps().is_cpu();
    let mut runs = Vec::new();
    for (res, points) in [(128u32, 10_000u32), (256, 50_000)] {
        let iterations = match (cpu, res) {
            (true, 128) => 20,
            (true, _) => 5,
            (false, _) => 100,
        };
        let b = tgs::bench_train::train(&ctx, res, points, 3, iterations)?;
        tgs::bench_train::print_train(&b);
        runs.push(b);
    }
    let date = std::process::Command::new("date").arg("-u").arg("+%Y-%m-%d").output().ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string()).unwrap_or_default();
    let p = tgs_perf::write_json("train", &json!({ "device": ctx.caps().describe(), "date": date, "runs": runs }))?;
    println!("wrote {}", p.display());
    Ok(())
}
