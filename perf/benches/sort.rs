//! `cargo bench`: radix sort and prefix sum for n = 2^16 .. 2^22 on the
//! default device (or TGS_DEVICE), per-kernel GPU times from timestamp
//! queries, throughput, and Rust's sort_unstable_by_key on the same data.
//! Results also go to target/tgs-bench/{sort,scan}.json.
//!
//! TGS_BENCH_MAX_LOG2 lowers the largest size (default 22).

use tgs_perf::wanted;

fn main() -> anyhow::Result<()> {
    if !wanted("sort") && !wanted("scan") {
        return Ok(());
    }
    let max_log2: u32 = std::env::var("TGS_BENCH_MAX_LOG2").ok().and_then(|v| v.parse().ok()).unwrap_or(22);
    let ctx = tgs_perf::context()?;
    if wanted("sort") {
        let mut runs = Vec::new();
        for log2 in 16..=max_log2 {
            let n = 1u32 << log2;
            let reps = if log2 >= 21 { 3 } else { 5 };
            let b = tgs::bench::sort(&ctx, n, 32, reps, None)?;
            tgs::bench::print_sort(&b);
            anyhow::ensure!(b.verified, "unsorted output at n={n}");
            runs.push(b);
        }
        tgs_perf::write_runs("sort", &ctx, serde_json::to_value(runs)?)?;
    }
    if wanted("scan") {
        let mut runs = Vec::new();
        for log2 in 16..=max_log2 {
            let b = tgs::bench::scan(&ctx, 1u32 << log2, 5)?;
            tgs::bench::print_scan(&b);
            runs.push(b);
        }
        tgs_perf::write_runs("scan", &ctx, serde_json::to_value(runs)?)?;
    }
    Ok(())
}
