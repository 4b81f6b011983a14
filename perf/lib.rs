//! Helpers for the `cargo bench` suite: where JSON results go.

use std::path::PathBuf;

/// `target/tgs-bench/` (or under `CARGO_TARGET_DIR`).
pub fn out_dir() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR").map(PathBuf::from).unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../target"));
    target.join("tgs-bench")
}

/// Write `value` as pretty JSON to `target/tgs-bench/NAME.json`.
pub fn write_json(name: &str, value: &serde_json::Value) -> anyhow::Result<PathBuf> {
    let dir = out_dir();
    std::fs::create_dir_all(&dir)?;
    let path = dir.join(format!("{name}.json"));
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_string_pretty(value)?)?;
    std::fs::rename(&tmp, &path)?;
    Ok(path)
}

/// `cargo bench -- NAME` runs only the benches whose name contains NAME.
pub fn wanted(name: &str) -> bool {
    std::env::args().skip(1).find(|a| !a.starts_with('-')).is_none_or(|f| name.contains(f.as_str()))
}

/// The benchmarks' context: the default device (or `TGS_DEVICE`), no
/// validation layer. Prints the device.
pub fn context() -> anyhow::Result<std::sync::Arc<tgs_engine::Context>> {
    use tgs_engine::{Context, ContextOptions, DeviceSelector};
    let ctx = Context::new(&ContextOptions { device: DeviceSelector::from_arg_or_env(None), validation: Some(false) })?;
    println!("device: {}", ctx.caps().describe());
    Ok(ctx)
}

/// Write `target/tgs-bench/NAME.json`: the device, today's date (UTC) and `runs`.
pub fn write_runs(name: &str, ctx: &tgs_engine::Context, runs: serde_json::Value) -> anyhow::Result<PathBuf> {
    let date = std::process::Command::new("date").arg("-u").arg("+%Y-%m-%d").output().ok().map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string()).unwrap_or_default();
    let p = write_json(name, &serde_json::json!({ "device": ctx.caps().describe(), "date": date, "runs": runs }))?;
    println!("wrote {}", p.display());
    Ok(p)
}
