//! `cargo bench --bench train`: whole training iterations (forward, loss,
//! backward, reduce, Adam; Gaussian count frozen) on Brush's workload, the
//! spheres scene: 10k Gaussians at 128² and 50k at 256², 20 views, SH 3.
//! Prints the device, wall and per-kernel GPU ms per iteration, and Brush's
//! time on the reference lavapipe machine; JSON to target/tgs-bench/train.json.

fn main() -> anyhow::Result<()> {
    if !tgs_perf::wanted("train") {
        return Ok(());
    }
    let ctx = tgs_perf::context()?;
    let cpu = ctx.caps().is_cpu();
    let mut runs = Vec::new();
    for (res, points) in [(128u32, 10_000u32), (256, 50_000)] {
        let iterations = match (cpu, res) {
            (true, 128) => 20,
            (true, _) => 5,
            (false, _) => 100,
        };
        let b = tgs::bench_train::train(&ctx, res, points, 3, iterations, true)?;
        tgs::bench_train::print_train(&b);
        runs.push(b);
    }
    tgs_perf::write_runs("train", &ctx, serde_json::to_value(runs)?)?;
    Ok(())
}
