//! `tgs bench mlp` / `cargo bench --bench mlp`: the light-field MLP's
//! encode, forward, backward and reduce on N random samples, GPU ms per
//! kernel (timestamp queries), samples/s and GFLOP/s.

use crate::bench::{average, KernelTime};
use anyhow::Result;
use serde::Serialize;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::mlp::{Gemm, Mlp, MlpShape, OUT, SAMPLE};

#[derive(Clone, Debug, Serialize)]
pub struct MlpBench {
    pub device: String,
    pub shape: String,
    /// The GEMM kernel: tiled or rows.
    pub gemm: String,
    pub params: u32,
    pub samples: u32,
    pub reps: u32,
    pub kernels: Vec<KernelTime>,
    pub forward_ms: f64,
    pub backward_ms: f64,
    /// Forward + backward samples per second (GPU time).
    pub samples_per_s: f64,
    /// 2 x multiply-adds of the forward / its GPU time.
    pub forward_gflops: f64,
    /// Weight and input gradients (about 2x the forward's multiply-adds) / their GPU time.
    pub backward_gflops: f64,
    /// Host submit-to-completion, ms per forward + backward (best of reps).
    pub wall_ms: f64,
    pub scratch_mib: f64,
}

/// `gemm`: the kernel, or None for the device's ([`Gemm::for_device`]).
pub fn mlp(ctx: &Arc<Context>, shape: MlpShape, n: u32, reps: u32, gemm: Option<Gemm>) -> Result<MlpBench> {
    anyhow::ensure!(reps > 0, "--reps must be at least 1");
    shape.validate()?;
    // Activations: one width-wide f32 row per sample and layer.
    let row = 4 * shape.width.max(SAMPLE) as u64;
    crate::bench::check_size(ctx, "--n", n as u64, row * n as u64, row * n as u64 * (shape.depth as u64 + 2) * 2)?;
    let m = match gemm {
        Some(g) => Mlp::with_gemm(ctx, g)?,
        None => Mlp::new(ctx)?,
    };
    let s = m.scratch(shape, n)?;
    let mut st = 0x3c6ef372u32;
    let mut next = || {
        st ^= st << 13;
        st ^= st >> 17;
        st ^= st << 5;
        st as f32 / u32::MAX as f32 * 2.0 - 1.0
    };
    let samples: Vec<f32> = (0..n * SAMPLE).map(|_| next()).collect();
    s.samples.upload(&samples)?;
    let params = Buffer::from_slice(ctx, "bench.mlp_params", &shape.init_params(7))?;
    let d_out = Buffer::from_slice(ctx, "bench.mlp_dout", &(0..n * OUT).map(|_| next()).collect::<Vec<_>>())?;
    let grads = Buffer::uninit(ctx, "bench.mlp_grads", shape.params() as usize)?;
    let mut timings = Vec::new();
    let mut wall = f64::INFINITY;
    for rep in 0..=reps {
        let mut rec = Recorder::with_profiling(ctx, 64)?;
        m.record_forward(&mut rec, &params, n, &s)?;
        m.record_backward(&mut rec, &params, n, &d_out, &grads, &s)?;
        let t0 = Instant::now();
        let t = rec.submit_and_wait()?;
        if rep > 0 {
            timings.push(t);
            wall = wall.min(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    let kernels: Vec<KernelTime> = average(timings).into_iter().filter(|k| k.name.starts_with("mlp.")).collect();
    let ms = |name: &str| kernels.iter().filter(|k| k.name == name).map(|k| k.ms).sum::<f64>();
    let forward_ms = ms("mlp.encode") + ms("mlp.forward");
    let backward_ms = ms("mlp.backward") + ms("mlp.reduce");
    let flop = 2.0 * shape.macs() as f64 * n as f64;
    let (fwd, bwd) = (ms("mlp.forward"), ms("mlp.backward"));
    Ok(MlpBench {
        device: ctx.caps().describe(),
        shape: format!("{} x {}, skip {}, L {}/{}", shape.depth, shape.width, shape.skip, shape.levels_x, shape.levels_w),
        gemm: m.gemm().name().into(),
        params: shape.params(),
        samples: n,
        reps,
        kernels,
        forward_ms,
        backward_ms,
        samples_per_s: n as f64 / ((forward_ms + backward_ms) * 1e-3),
        forward_gflops: flop / (fwd * 1e6),
        backward_gflops: 2.0 * flop / (bwd * 1e6),
        wall_ms: wall,
        scratch_mib: s.bytes() as f64 / (1 << 20) as f64,
    })
}

pub fn print_mlp(b: &MlpBench) {
    println!(
        "mlp [{}] ({} params, {} kernel) on {} samples: forward {:.2} ms ({:.2} GFLOP/s), backward {:.2} ms ({:.2} GFLOP/s), {:.0} samples/s, wall {:.2} ms, scratch {:.1} MiB",
        b.shape, b.params, b.gemm, b.samples, b.forward_ms, b.forward_gflops, b.backward_ms, b.backward_gflops, b.samples_per_s, b.wall_ms, b.scratch_mib
    );
    for k in &b.kernels {
        println!("    {:<16} {:>10.3} ms  ({} calls)", k.name, k.ms, k.calls);
    }
}
