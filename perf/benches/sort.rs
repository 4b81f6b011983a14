//! `cargo bench`: radix sort and prefix sum for n = 2^16 .. 2^22 on the
//! default device (or TGS_DEVICE), per-kernel GPU times from timestamp
//! queries, throughput, and Rust's sort_unstable_by_key on the same data.
//! Results also go to target/tgs-bench/{sort,scan}.json.
//!
//! TGS_BENCH_MAX_LOG2 lowers the largest size (default 22).

use serde_json::json;
use tgs_engine::{Context, ContextOptions, DeviceSelector};

fn main() -> anyhow::Result<()> {
    // `cargo bench -- NAME` filters: run only benches whose name contains NAME.
    let filter: Option<String> = std::env::args().skip(1).find(|a| !a.starts_with('-'));
    let want = |name: &str| filter.as_deref().is_none_or(|f| name.contains(f));
    let max_log2: u32 = std::env::var("TGS_BENCH_MAX_LOG2").ok().and_then(|v| v.parse().ok()).unwrap_or(22);
    let ctx = Context::new(&ContextOptions { device: DeviceSelector::from_arg_or_env(None), validation: Some(false) })?;
    println!("device: {}", ctx.caps().describe());
    let date = std::process::Command::new("date").arg("-u").arg("+%Y-%m-%d").output().ok()
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string()).unwrap_or_default();
    if want("sort") {
        let mut runs = Vec::new();
        for log2 in 16..=max_log2 {
            let n = 1u32 << log2;
            let reps = if log2 >= 21 { 3 } else { 5 };
            let b = tgs::bench::sort(&ctx, n, 32, reps, None)?;
            tgs::bench::print_sort(&b);
            anyhow::ensure!(b.verified, "unsorted output at n={n}");
            runs.push(b);
        }
        let p = tgs_perf::write_json("sort", &json!({ "device": ctx.caps().describe(), "date": date, "runs": runs }))?;
        println!("wrote {}", p.display());
    }
    if want("scan") {
        let mut runs = Vec::new();
        for log2 in 16..=max_log2 {
            let b = tgs::bench::scan(&ctx, 1u32 << log2, 5)?;
            tgs::bench::print_scan(&b);
            runs.push(b);
        }
        let p = tgs_perf::write_json("scan", &json!({ "device": ctx.caps().describe(), "date": date, "runs": runs }))?;
        println!("wrote {}", p.display());
    }
    Ok(())
}
