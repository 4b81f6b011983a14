//! `cargo bench --bench stages`: Stage I, II and III iterations on the
//! built-in glass scene with each Stage III network preset: GPU ms per
//! kernel per stage, wall ms per iteration, memory, the device. JSON goes to
//! target/tgs-bench/stages.json.

fn main() -> anyhow::Result<()> {
    if !tgs_perf::wanted("stages") {
        return Ok(());
    }
    let ctx = tgs_perf::context()?;
    let iterations = if ctx.caps().is_cpu() { 10 } else { 50 };
    let mut runs = Vec::new();
    for mlp in ["small", "paper"] {
        let spec = tgs::bench_stages::StagesSpec { scene: "glass".into(), train: 300, train_light_field: 50, warmup: 3, iterations, mlp: mlp.into(), set: vec![] };
        let b = tgs::bench_stages::stages(&ctx, &spec)?;
        tgs::bench_stages::print_stages(&b);
        runs.push(b);
    }
    tgs_perf::write_runs("stages", &ctx, serde_json::to_value(runs)?)?;
    Ok(())
}
