//! `cargo bench --bench raster`: the 2DGS rasterizer (forward + backward)
//! on synthetic scenes, per-kernel GPU times from timestamp queries,
//! intersections per second, and the device. Sizes: 10k at 128², 100k at
//! 256², and 300k at 800² where the device has the memory (skip it with
//! TGS_BENCH_RASTER_LARGE=0). JSON goes to target/tgs-bench/raster.json.

fn main() -> anyhow::Result<()> {
    if !tgs_perf::wanted("raster") {
        return Ok(());
    }
    let ctx = tgs_perf::context()?;
    let large = std::env::var("TGS_BENCH_RASTER_LARGE").map(|v| v != "0").unwrap_or(true);
    let reps = if ctx.caps().is_cpu() { 2 } else { 10 };
    let mut sizes = vec![(10_000u32, 128u32, 128u32), (100_000, 256, 256)];
    if large {
        sizes.push((300_000, 800, 800));
    }
    let mut runs = Vec::new();
    for (n, w, h) in sizes {
        match tgs::bench_raster::raster(&ctx, n, w, h, if w > 256 { 1 } else { reps }) {
            Ok(b) => {
                tgs::bench_raster::print_raster(&b);
                runs.push(b);
            }
            // A device without the memory for a size says so and goes on.
            Err(e) => println!("raster {n} Gaussians at {w}x{h}: skipped: {e:#}"),
        }
    }
    tgs_perf::write_runs("raster", &ctx, serde_json::to_value(runs)?)?;
    Ok(())
}
