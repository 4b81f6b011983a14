//! `cargo bench --bench mlp`: the light-field MLP (encode, forward,
//! backward, reduce) for both presets on 1,024 and 4,096 samples, on the
//! three kernels (tiled, rows, fused: bit-identical results), GPU ms per
//! kernel, samples/s and GFLOP/s, and the device. JSON goes to
//! target/tgs-bench/mlp.json.

use tgs_pipelines::mlp::Gemm;

fn main() -> anyhow::Result<()> {
    if !tgs_perf::wanted("mlp") {
        return Ok(());
    }
    let ctx = tgs_perf::context()?;
    let reps = if ctx.caps().is_cpu() { 2 } else { 10 };
    let mut runs = Vec::new();
    for preset in ["paper", "small"] {
        for n in [1024u32, 4096] {
            for gemm in [Gemm::Tiled, Gemm::Rows, Gemm::Fused] {
                let b = tgs::bench_mlp::mlp(&ctx, tgs_pipelines::MlpShape::preset(preset)?, n, reps, Some(gemm))?;
                tgs::bench_mlp::print_mlp(&b);
                runs.push(b);
            }
        }
    }
    tgs_perf::write_runs("mlp", &ctx, serde_json::to_value(runs)?)?;
    Ok(())
}
