//! Benchmarks of the sort and scan kernels, shared by `tgs bench` and
//! `cargo bench` (perf/). GPU times come from timestamp queries per kernel.

use anyhow::{bail, Context as _, Result};
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::{summarize, Buffer, Context, Recorder};
use tgs_pipelines::{Count, PrefixSum, RadixSort, ScanScratch, SortConfig};

/// Whether a timed scope runs inside another one (the sort and scan passes
/// nest in the rasterizer's and the texel reduction's scopes): summing
/// GPU time per iteration skips these.
pub fn nested_scope(name: &str) -> bool {
    name.starts_with("sort.") || name.starts_with("scan.")
}

/// Per-kernel GPU time, averaged over the timed repetitions.
#[derive(Clone, Debug, Serialize)]
pub struct KernelTime {
    pub name: String,
    /// Milliseconds per run, summed over this kernel's dispatches.
    pub ms: f64,
    /// Dispatches (or scopes) per run.
    pub calls: usize,
}

#[derive(Clone, Debug, Serialize)]
pub struct SortBench {
    pub device: String,
    pub n: u32,
    pub bits: u32,
    pub config: String,
    pub reps: u32,
    pub kernels: Vec<KernelTime>,
    /// Sum of the per-kernel GPU times, ms per sort.
    pub gpu_ms: f64,
    /// Host-measured submit-to-completion time, ms per sort (best of reps).
    pub wall_ms: f64,
    pub gpu_mkeys_per_s: f64,
    /// Rust `slice::sort_unstable_by_key` on the same (key, value) pairs, ms (best of reps).
    pub cpu_sort_unstable_ms: f64,
    pub cpu_mkeys_per_s: f64,
    /// cpu_sort_unstable_ms / gpu_ms
    pub speedup_vs_cpu: f64,
    pub verified: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct ScanBench {
    pub device: String,
    pub n: u32,
    pub reps: u32,
    pub kernels: Vec<KernelTime>,
    pub gpu_ms: f64,
    pub gpu_melems_per_s: f64,
    pub cpu_ms: f64,
}

fn keys(n: u32, seed: u64) -> Vec<u32> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 32) as u32
        })
        .collect()
}

/// Per-kernel times averaged over repetitions (each a run's timings).
pub(crate) fn average(all: Vec<Vec<tgs_engine::Timing>>) -> Vec<KernelTime> {
    let reps = all.len().max(1) as f64;
    let mut out: Vec<KernelTime> = Vec::new();
    for t in &all {
        for s in summarize(t) {
            match out.iter_mut().find(|k| k.name == s.name) {
                Some(k) => k.ms += s.total_ms / reps,
                None => out.push(KernelTime { name: s.name, ms: s.total_ms / reps, calls: s.count }),
            }
        }
    }
    out
}

/// Refuse a benchmark size before any host or device memory is taken:
/// `count` items of `what` with `largest` bytes in the largest single
/// buffer and `total` bytes in all must fit the device's storage-binding
/// range and its memory. `flag` names the option to lower.
pub fn check_size(ctx: &Context, flag: &str, count: u64, largest: u64, total: u64) -> Result<()> {
    let c = ctx.caps();
    let range = c.max_storage_buffer_range;
    if count == 0 {
        bail!("{flag} 0: nothing to time (give at least 1)");
    }
    if largest > range {
        bail!(
            "{flag} {count}: its largest buffer would be {:.1} MiB, over {}'s {:.0} MiB per storage binding (at most {} at this size)",
            largest as f64 / 1048576.0,
            c.device_name,
            range as f64 / 1048576.0,
            (count as u128 * range as u128 / largest as u128)
        );
    }
    if c.device_local_bytes > 0 && total > c.device_local_bytes {
        bail!(
            "{flag} {count}: it needs about {:.1} GiB, more than {}'s {:.1} GiB of device memory",
            total as f64 / (1u64 << 30) as f64,
            c.device_name,
            c.device_local_bytes as f64 / (1u64 << 30) as f64
        );
    }
    Ok(())
}

/// Time the radix sort of `n` random keys (low `bits` bits), `reps` timed runs after one warm-up.
pub fn sort(ctx: &Arc<Context>, n: u32, bits: u32, reps: u32, cfg: Option<SortConfig>) -> Result<SortBench> {
    if bits == 0 || bits > 32 {
        bail!("--bits must be 1..=32, not {bits}");
    }
    if reps == 0 {
        bail!("--reps must be at least 1");
    }
    // Keys, values and their ping-pong copies (u32 each).
    check_size(ctx, "--n", n as u64, 4 * n as u64, 16 * n as u64)?;
    let sorter = match cfg {
        Some(c) => RadixSort::with_config(ctx, c)?,
        None => RadixSort::new(ctx)?,
    };
    let mask = if bits == 32 { u32::MAX } else { (1u32 << bits) - 1 };
    let k: Vec<u32> = keys(n, 0x5eed ^ n as u64).into_iter().map(|x| x & mask).collect();
    let v: Vec<u32> = (0..n).collect();
    let kb = Buffer::new(ctx, "bench.keys", n as usize)?;
    let vb = Buffer::new(ctx, "bench.vals", n as usize)?;
    let scratch = sorter.scratch(n)?;
    let mut timings = Vec::new();
    let mut wall = f64::INFINITY;
    let mut verified = true;
    for rep in 0..=reps {
        kb.upload(&k)?;
        vb.upload(&v)?;
        let mut rec = Recorder::with_profiling(ctx, 512)?;
        sorter.record(&mut rec, &kb, &vb, &Count::Host(n), bits, &scratch)?;
        let t0 = Instant::now();
        let t = rec.submit_and_wait()?;
        let w = t0.elapsed().as_secs_f64() * 1e3;
        if rep > 0 {
            timings.push(t);
            wall = wall.min(w);
        } else {
            let out = kb.download()?;
            verified = out.windows(2).all(|w| w[0] <= w[1]) && out.len() == k.len();
        }
    }
    let kernels = average(timings);
    let gpu_ms: f64 = kernels.iter().map(|k| k.ms).sum();

    let mut cpu = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let mut pairs: Vec<(u32, u32)> = k.iter().copied().zip(v.iter().copied()).collect();
        let t0 = Instant::now();
        pairs.sort_unstable_by_key(|p| p.0);
        cpu = cpu.min(t0.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(&pairs);
    }
    let cfg = sorter.config();
    Ok(SortBench {
        device: ctx.caps().describe(),
        n,
        bits,
        config: format!("wg {} kpt {} radix_bits {}", cfg.wg, cfg.kpt, cfg.radix_bits),
        reps,
        kernels,
        gpu_ms,
        wall_ms: wall,
        gpu_mkeys_per_s: n as f64 / (gpu_ms * 1e3),
        cpu_sort_unstable_ms: cpu,
        cpu_mkeys_per_s: n as f64 / (cpu * 1e3),
        speedup_vs_cpu: cpu / gpu_ms,
        verified,
    })
}

/// Time the exclusive prefix sum of `n` u32.
pub fn scan(ctx: &Arc<Context>, n: u32, reps: u32) -> Result<ScanBench> {
    if reps == 0 {
        bail!("--reps must be at least 1");
    }
    check_size(ctx, "--n", n as u64, 4 * n as u64, 12 * n as u64)?;
    let scan = PrefixSum::new(ctx)?;
    let x: Vec<u32> = keys(n, 7).into_iter().map(|v| v & 0xff).collect();
    let src = Buffer::from_slice(ctx, "bench.src", &x)?;
    let dst = Buffer::<u32>::new(ctx, "bench.dst", n as usize)?;
    let scratch = ScanScratch::new(ctx, n)?;
    let mut timings = Vec::new();
    for rep in 0..=reps {
        let mut rec = Recorder::with_profiling(ctx, 64)?;
        scan.record(&mut rec, &src, &dst, &Count::Host(n), &scratch)?;
        let t = rec.submit_and_wait()?;
        if rep > 0 {
            timings.push(t);
        }
    }
    let kernels = average(timings);
    let gpu_ms: f64 = kernels.iter().map(|k| k.ms).sum();
    let mut cpu = f64::INFINITY;
    for _ in 0..reps.max(1) {
        let t0 = Instant::now();
        let mut acc = 0u32;
        let out: Vec<u32> = x
            .iter()
            .map(|&v| {
                let r = acc;
                acc = acc.wrapping_add(v);
                r
            })
            .collect();
        std::hint::black_box(&out);
        cpu = cpu.min(t0.elapsed().as_secs_f64() * 1e3);
    }
    Ok(ScanBench { device: ctx.caps().describe(), n, reps, kernels, gpu_ms, gpu_melems_per_s: n as f64 / (gpu_ms * 1e3), cpu_ms: cpu })
}

pub fn print_sort(b: &SortBench) {
    println!(
        "sort n={} bits={} [{}]: GPU {:.3} ms ({:.1} Mkeys/s), wall {:.3} ms; CPU sort_unstable_by_key {:.3} ms ({:.1} Mkeys/s); GPU/CPU speed-up {:.2}x{}",
        b.n,
        b.bits,
        b.config,
        b.gpu_ms,
        b.gpu_mkeys_per_s,
        b.wall_ms,
        b.cpu_sort_unstable_ms,
        b.cpu_mkeys_per_s,
        b.speedup_vs_cpu,
        if b.verified { "" } else { "  ** OUTPUT NOT SORTED **" }
    );
    for k in &b.kernels {
        println!("    {:<16} {:>10.3} ms  ({} calls)", k.name, k.ms, k.calls);
    }
}

pub fn print_scan(b: &ScanBench) {
    println!("scan n={}: GPU {:.3} ms ({:.1} Melems/s); CPU {:.3} ms", b.n, b.gpu_ms, b.gpu_melems_per_s, b.cpu_ms);
    for k in &b.kernels {
        println!("    {:<16} {:>10.3} ms  ({} calls)", k.name, k.ms, k.calls);
    }
}

/// `tgs bench lpips`: LPIPS of two `size` x `size` images on the CPU
/// (seconds per pair, GFLOP/s of the convolutions), after one warm-up.
pub fn lpips(size: u32, reps: u32, json: bool) -> Result<()> {
    use crate::lpips::{shared, weights_path, CONVS, MIN_SIDE};
    let s = size as usize;
    if !(MIN_SIDE..=4096).contains(&s) {
        bail!("--size must be {MIN_SIDE}..=4096 (LPIPS needs {MIN_SIDE} pixels a side; larger feature maps would take gigabytes), not {size}");
    }
    if reps == 0 {
        bail!("--reps must be at least 1");
    }
    let net = shared().with_context(|| format!("no LPIPS weights at {}", weights_path().display()))?;
    let img = |k: usize| -> Vec<f32> { (0..3 * s * s).map(|i| ((i * (7 + k) + i / s * 13) % 97) as f32 / 96.0).collect() };
    let (a, b) = (img(0), img(1));
    // Multiply-adds of the five convolutions, for both images.
    let (mut h, mut flops) = (s, 0.0f64);
    for (l, &(k, st, p, ci, co)) in CONVS.iter().enumerate() {
        if l == 1 || l == 2 {
            h = (h - 3) / 2 + 1;
        }
        h = (h + 2 * p - k) / st + 1;
        flops += 2.0 * 2.0 * (h * h * k * k * ci * co) as f64;
    }
    net.distance(&a, &b, s, s);
    let t = std::time::Instant::now();
    let mut d = 0.0;
    for _ in 0..reps {
        d = net.distance(&a, &b, s, s).unwrap_or(f64::NAN);
    }
    let sec = t.elapsed().as_secs_f64() / reps as f64;
    let threads = std::thread::available_parallelism().map(|t| t.get()).unwrap_or(1);
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| c.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(|m| m.trim().to_string()))
        .unwrap_or_else(|| "unknown CPU".into());
    let device = format!("CPU: {cpu}, {threads} threads");
    if json {
        println!("{}", serde_json::json!({"device": device, "size": size, "reps": reps, "seconds_per_pair": sec, "gflop_per_s": flops / sec / 1e9, "lpips": d}));
    } else {
        println!("device: {device}");
        println!("LPIPS {size}x{size}: {:.3} s per image pair, {:.2} GFLOP/s ({:.1} GFLOP), value {d:.4}", sec, flops / sec / 1e9, flops / 1e9);
    }
    Ok(())
}
