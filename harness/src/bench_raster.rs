//! Benchmark of the 2DGS rasterizer: a synthetic scene of N Gaussians at
//! W x H, one forward + backward per repetition, GPU time per kernel from
//! timestamp queries. Shared by `tgs bench raster` and `cargo bench`.

use crate::bench::{average, KernelTime};
use anyhow::{ensure, Result};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::{Context, Recorder};
use tgs_pipelines::{Camera, Features, Gaussians, HostGaussians, Rasterizer};

#[derive(Clone, Debug, Serialize)]
pub struct RasterBench {
    pub device: String,
    pub gaussians: u32,
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    pub sh_degree: u32,
    pub reps: u32,
    pub intersections: u32,
    pub span: u32,
    pub spans: u32,
    /// Per scope: raster.* kernels, the two sorts as a whole, and their sort.* passes.
    pub kernels: Vec<KernelTime>,
    pub forward_ms: f64,
    pub backward_ms: f64,
    /// GPU time of forward + backward, ms (one timestamp pair around both).
    pub total_ms: f64,
    /// Host-measured submit-to-completion, ms (best of reps).
    pub wall_ms: f64,
    pub intersections_per_s: f64,
    /// How the backward reached the gradient records (binding or address).
    pub records: String,
    /// Device bytes per intersection of frame capacity, and the peak device
    /// memory of the run (scene, gradients, frame), MiB.
    pub bytes_per_intersection: u64,
    pub peak_memory_mib: f64,
}

/// A deterministic synthetic scene: Gaussians in a box in front of the
/// camera, random orientations, sizes of a few pixels to a few tiles.
pub fn synthetic_scene(n: u32, seed: u64) -> HostGaussians {
    let mut s = seed;
    let mut next = move || {
        s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((s >> 11) as f64 / (1u64 << 53) as f64) as f32
    };
    let mut h = HostGaussians::new(3, 16);
    for _ in 0..n {
        let mean = [next() * 2.0 - 1.0, next() * 2.0 - 1.0, next() * 2.0 - 1.0];
        let ls = [-4.5 + 2.0 * next(), -4.5 + 2.0 * next()];
        let q = [next() - 0.5, next() - 0.5, next() - 0.5, next() - 0.5];
        let feats: Vec<f32> = (0..48).map(|i| if i < 3 { next() * 2.0 - 1.0 } else { (next() - 0.5) * 0.2 }).collect();
        h.push(mean, ls, q, next() * 4.0 - 2.0, &feats);
    }
    h
}

pub fn bench_camera(width: u32, height: u32) -> Camera {
    Camera::look_at([0.0, 0.0, -3.2], [0.0, 0.0, 0.0], [0.0, -1.0, 0.0], 0.8, width, height)
}

pub fn raster(ctx: &Arc<Context>, n: u32, width: u32, height: u32, reps: u32) -> Result<RasterBench> {
    ensure!(reps > 0, "--reps must be at least 1");
    ensure!(width > 0 && height > 0 && width <= 16384 && height <= 16384, "--width and --height must be 1..=16384, not {width}x{height}");
    // SH 3: 48 feature floats a Gaussian (the largest array), about 59
    // floats of parameters and as many of gradients in all; 4 intersections
    // a Gaussian of 8 bytes; 16 planes of frame per pixel.
    let px = width as u64 * height as u64;
    crate::bench::check_size(ctx, "--n", n as u64, (48 * 4 * n as u64).max(32 * n as u64), 2 * 59 * 4 * n as u64 + 32 * n as u64 + 64 * px)?;
    ctx.reset_peak_memory();
    let rast = Rasterizer::new(ctx, 3, Features::Sh { degree: 3 })?;
    let host = synthetic_scene(n, 7);
    let g = Gaussians::upload(ctx, &host)?;
    let grads = Gaussians::zeros(ctx, g.n, g.channels, g.coeffs)?;
    let cam = bench_camera(width, height);
    let bg = [0.0f32; 3];
    let mut frame = rast.frame(width, height, n, (n * 4).clamp(1024, rast.max_capacity()))?;
    // Warm-up: grows the frame to fit, compiles everything.
    rast.forward(&g, &cam, &bg, 3, &mut frame, false)?;
    let planes = tgs_pipelines::Plane::count(3) as usize;
    let go: Vec<f32> = (0..planes * frame.pixels()).map(|i| ((i * 7919) % 200) as f32 / 100.0 - 1.0).collect();
    frame.grad_out.upload(&go)?;

    let mut all = Vec::new();
    let mut wall = f64::INFINITY;
    for _ in 0..reps {
        let mut rec = Recorder::with_profiling(ctx, 512)?;
        let total = rec.begin_scope("total");
        let f = rec.begin_scope("forward");
        rast.record_forward(&mut rec, &g, &cam, &bg, 3, &frame)?;
        rec.end_scope(f);
        let b = rec.begin_scope("backward");
        rast.record_backward(&mut rec, &g, &grads, 3, &frame)?;
        rec.end_scope(b);
        rec.end_scope(total);
        let t0 = Instant::now();
        let t = rec.submit_and_wait()?;
        wall = wall.min(t0.elapsed().as_secs_f64() * 1e3);
        ensure!(rast.fit(&mut frame)?, "the frame grew during timed runs");
        all.push(t);
    }
    let mut kernels = average(all);
    let take = |name: &str, ks: &mut Vec<KernelTime>| {
        let i = ks.iter().position(|k| k.name == name);
        i.map(|i| ks.remove(i).ms).unwrap_or(0.0)
    };
    let total_ms = take("total", &mut kernels);
    let forward_ms = take("forward", &mut kernels);
    let backward_ms = take("backward", &mut kernels);
    let isects = frame.last_intersections;
    Ok(RasterBench {
        device: ctx.caps().describe(),
        gaussians: n,
        width,
        height,
        channels: 3,
        sh_degree: 3,
        reps,
        intersections: isects,
        span: rast.span(),
        spans: frame.spans,
        records: format!("{:?}", rast.records()).to_lowercase(),
        bytes_per_intersection: rast.bytes_per_intersection(),
        peak_memory_mib: ctx.memory_use().peak_bytes as f64 / 1048576.0,
        kernels,
        forward_ms,
        backward_ms,
        total_ms,
        wall_ms: wall,
        intersections_per_s: isects as f64 / (total_ms / 1e3),
    })
}

pub fn print_raster(b: &RasterBench) {
    println!(
        "raster {} Gaussians at {}x{} (SH 3, C {}): {} intersections, {} span pass(es) of {}\n  forward {:.2} ms + backward {:.2} ms = {:.2} ms GPU ({:.2} ms wall), {:.2} M intersections/s  [{}]\n  device memory: peak {:.1} MiB; {} bytes per intersection of frame capacity (records by {})",
        b.gaussians, b.width, b.height, b.channels, b.intersections, b.spans, b.span, b.forward_ms, b.backward_ms, b.total_ms, b.wall_ms, b.intersections_per_s / 1e6, b.device, b.peak_memory_mib, b.bytes_per_intersection, b.records
    );
    for k in &b.kernels {
        let indent = if crate::bench::nested_scope(&k.name) { "      " } else { "    " };
        println!("{indent}{:<20} {:>10.3} ms  ({} calls)", k.name, k.ms, k.calls);
    }
}
