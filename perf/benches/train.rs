//! `cargo bench --bench train`: whole training iterations (forward, loss,
//! backward, reduce, Adam; Gaussian count frozen) on Brush's workload, the
//! spheres scene: 10k Gaussians at 128² and 50k at 256², 20 views, SH 3.
//! Then the real-scale workload (a Mip-NeRF 360 frame, 1237x822, and a
//! million Gaussians) on GPUs, and on CPU devices when
//! `TGS_BENCH_REAL_SCALE=1` (one timed iteration: minutes on lavapipe),
//! and a Stage III iteration at that frame (the small light field).
//! Prints the device, wall and per-kernel GPU ms per iteration, and Brush's
//! time on the reference lavapipe machine; JSON to target/tgs-bench/train.json.
//! `TGS_BENCH_TRAIN_FROM=RUN` adds Stage I iterations on that `tgs train`
//! run's own model and views (`tgs bench train --from RUN`).

fn main() -> anyhow::Result<()> {
    if !tgs_perf::wanted("train") {
        return Ok(());
    }
    let ctx = tgs_perf::context()?;
    let cpu = ctx.caps().is_cpu();
    let mut runs = Vec::new();
    use tgs::bench_train::Workload;
    let mut workloads = vec![(Workload::square(128, 10_000), if cpu { 20 } else { 100 }), (Workload::square(256, 50_000), if cpu { 5 } else { 100 })];
    if !cpu || std::env::var("TGS_BENCH_REAL_SCALE").is_ok_and(|v| v == "1") {
        // The features of a million Gaussians (183 MiB at SH 3) exceed one
        // storage binding on lavapipe (128 MiB); the rasterizer binds them
        // in slices there.
        workloads.push((Workload::REAL_SCALE, if cpu { 1 } else { 20 }));
    }
    let real = workloads.iter().any(|(w, _)| *w == Workload::REAL_SCALE);
    for (w, iterations) in workloads {
        let b = tgs::bench_train::train(&ctx, w, 3, iterations, None)?;
        tgs::bench_train::print_train(&b);
        runs.push(b);
    }
    // Stage III at the real-scale frame (`tgs bench train --real-scale
    // --light-field small`).
    let mut light = Vec::new();
    if real {
        let b = tgs::bench_light_field::light_field(&ctx, Workload::REAL_SCALE, 1, if cpu { 1 } else { 20 }, tgs::train::stages::light_field::settings::LightPreset::Small)?;
        tgs::bench_light_field::print_light_field(&b);
        light.push(b);
    }
    if let Some(run) = std::env::var_os("TGS_BENCH_TRAIN_FROM").map(std::path::PathBuf::from) {
        let b = tgs::bench_train::train_from(&ctx, &run, 3, if cpu { 20 } else { 100 }, None)?;
        println!("trained model of {}:", run.display());
        tgs::bench_train::print_train(&b);
        runs.push(b);
    }
    tgs_perf::write_runs("train", &ctx, serde_json::json!({ "stage1": runs, "stage3": light }))?;
    Ok(())
}
