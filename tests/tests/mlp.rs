//! The light-field MLP (pipelines/src/mlp) against its f64 reference
//! (tests/src/mlp_ref.rs): the Fourier encoding at L = 12 for |x| <= 1 and
//! beyond, forward outputs and every parameter's gradient for small
//! networks (sample counts and widths not a multiple of any of the GEMM's
//! tile sizes, one weight-gradient chunk and many)
//! and the paper's 8 x 256 on a few samples; the reference's own gradient
//! against central differences; no NaN/Inf with saturated heads and huge or
//! denormal inputs; bit-identical reruns; the tiled (GPU) and row (CPU
//! device) GEMM kernels and the fused kernels bit-identical to each
//! other, and the fused kernels against the reference on their own.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::mlp::{weight_chunks, Gemm, Mlp, MlpShape, OUT};
use tgs_tests::mlp_ref;
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

fn uni(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

fn random_samples(rng: &mut Rng, n: usize, extent: f64) -> Vec<[f64; 6]> {
    (0..n)
        .map(|_| {
            let mut w = [0.0; 3];
            loop {
                for c in &mut w {
                    *c = uni(rng, -1.0, 1.0);
                }
                let l = w.iter().map(|v| v * v).sum::<f64>().sqrt();
                if l > 0.1 && l < 1.0 {
                    w = w.map(|v| v / l);
                    break;
                }
            }
            let r = |v: f64| v as f32 as f64;
            [r(uni(rng, -extent, extent)), r(uni(rng, -extent, extent)), r(uni(rng, -extent, extent)), r(w[0]), r(w[1]), r(w[2])]
        })
        .collect()
}

struct GpuRun {
    out: Vec<f32>,
    grads: Vec<f32>,
}

fn gpu(shape: MlpShape, params: &[f32], samples: &[[f64; 6]], d_out: &[[f64; 3]]) -> GpuRun {
    gpu_on(None, shape, params, samples, d_out)
}

/// As [`gpu`], on a chosen kernel (None: the device's).
fn gpu_on(gemm: Option<Gemm>, shape: MlpShape, params: &[f32], samples: &[[f64; 6]], d_out: &[[f64; 3]]) -> GpuRun {
    let ctx = ctx_shared();
    let mlp = match gemm {
        Some(g) => Mlp::with_gemm(ctx, g).unwrap(),
        None => Mlp::new(ctx).unwrap(),
    };
    let n = samples.len() as u32;
    let s = mlp.scratch(shape, n).unwrap();
    let flat: Vec<f32> = samples.iter().flat_map(|v| v.map(|c| c as f32)).collect();
    if !flat.is_empty() {
        s.samples.upload(&flat).unwrap();
    }
    let p = Buffer::from_slice(ctx, "params", params).unwrap();
    let d: Vec<f32> = d_out.iter().flat_map(|v| v.map(|c| c as f32)).collect();
    let d = Buffer::from_slice(ctx, "d_out", if d.is_empty() { &[0.0][..] } else { &d }).unwrap();
    let g = Buffer::uninit(ctx, "grads", params.len()).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    mlp.record_forward(&mut rec, &p, n, &s).unwrap();
    mlp.record_backward(&mut rec, &p, n, &d, &g, &s).unwrap();
    rec.submit_and_wait().unwrap();
    let out = if n > 0 { s.out.download_range(0, (n * OUT) as usize).unwrap() } else { vec![] };
    let r = GpuRun { out, grads: g.download().unwrap() };
    check_validation(ctx);
    r
}

/// |gpu - ref| <= tol (scale + |ref|) for every element, scale the
/// largest |ref|; returns the worst ratio.
fn compare(what: &str, gpu: &[f32], reference: &[f64], tol: f64) -> f64 {
    assert_eq!(gpu.len(), reference.len(), "{what}: lengths");
    let scale = reference.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-30);
    let mut worst = 0.0f64;
    for (i, (g, r)) in gpu.iter().zip(reference).enumerate() {
        assert!(g.is_finite(), "{what}[{i}] = {g}");
        let e = (*g as f64 - r).abs() / (tol * (scale + r.abs()));
        assert!(e <= 1.0, "{what}[{i}]: gpu {g} vs f64 {r} (scale {scale})");
        worst = worst.max(e);
    }
    worst
}

/// How far from a ReLU kink (|pre-activation|) a test sample must be: well
/// above the f32 error of a pre-activation (~1e-5 with 12 Fourier levels),
/// far below the values' scale (~0.1-1).
const KINK: f64 = 1e-4;

fn check_network(shape: MlpShape, n: usize, extent: f64, rng: &mut Rng) {
    check_network_on(None, shape, n, extent, rng)
}

/// As [`check_network`], on a chosen kernel (None: the device's).
fn check_network_on(gemm: Option<Gemm>, shape: MlpShape, n: usize, extent: f64, rng: &mut Rng) {
    let params: Vec<f32> = shape.init_params(rng.next_u64());
    let p64: Vec<f64> = params.iter().map(|&v| v as f64).collect();
    // Samples with a hidden unit within KINK of its ReLU's kink are drawn
    // again: f32 rounding may put the GPU on the other side of it.
    let samples: Vec<[f64; 6]> = (0..n)
        .map(|_| loop {
            let s = random_samples(rng, 1, extent)[0];
            if mlp_ref::kink_margin(&shape, &p64, &s) > KINK {
                break s;
            }
        })
        .collect();
    let d_out: Vec<[f64; 3]> = (0..n).map(|_| [0, 1, 2].map(|_| uni(rng, -1.0, 1.0) as f32 as f64)).collect();
    let run = gpu_on(gemm, shape, &params, &samples, &d_out);
    let out_ref: Vec<f64> = samples.iter().flat_map(|s| mlp_ref::forward(&shape, &p64, s).outputs.last().unwrap().clone()).collect();
    compare(&format!("{shape:?} n={n} outputs"), &run.out, &out_ref, 2e-5);
    let g_ref = mlp_ref::backward(&shape, &p64, &samples, &d_out);
    compare(&format!("{shape:?} n={n} gradients"), &run.grads, &g_ref, 1e-4);
}

const SMALL: MlpShape = MlpShape { depth: 3, width: 5, skip: 1, levels_x: 2, levels_w: 1 };

#[test]
fn small_networks_match_reference() {
    let mut rng = Rng(seed("mlp small"));
    // 1 sample, a partial tile, several tiles; 2,000 samples make 8 weight chunks.
    for n in [1, 37, 100] {
        check_network(SMALL, n, 1.0, &mut rng);
    }
    assert!(weight_chunks(2000).1 > 4);
    check_network(MlpShape { depth: 4, width: 40, skip: 2, levels_x: 6, levels_w: 4 }, 2000, 1.0, &mut rng);
    // Width above one tile, skip right before the head.
    check_network(MlpShape { depth: 2, width: 70, skip: 1, levels_x: 3, levels_w: 2 }, 65, 1.3, &mut rng);
    // The largest GEMM block (128-wide tiles) on partial tiles in every product.
    check_network(MlpShape { depth: 3, width: 130, skip: 2, levels_x: 4, levels_w: 3 }, 300, 1.0, &mut rng);
}

#[test]
fn paper_network_on_a_few_samples() {
    let mut rng = Rng(seed("mlp paper"));
    let shape = MlpShape::PAPER;
    assert_eq!(shape.cat_width(), 256 + 75 + 75);
    check_network(shape, 5, 1.0, &mut rng);
}

#[test]
fn reference_gradient_matches_finite_differences() {
    let mut rng = Rng(seed("mlp fd"));
    let shape = SMALL;
    let params: Vec<f64> = shape.init_params(rng.next_u64()).iter().map(|&v| v as f64).collect();
    let samples = random_samples(&mut rng, 4, 1.0);
    let d_out: Vec<[f64; 3]> = (0..4).map(|_| [0, 1, 2].map(|_| uni(&mut rng, -1.0, 1.0))).collect();
    let loss =
        |p: &[f64]| -> f64 { samples.iter().zip(&d_out).map(|(s, d)| mlp_ref::forward(&shape, p, s).outputs.last().unwrap().iter().zip(d).map(|(o, d)| o * d).sum::<f64>()).sum() };
    let g = mlp_ref::backward(&shape, &params, &samples, &d_out);
    let h = 1e-6;
    let mut checked = 0;
    for i in 0..params.len() {
        let mut p = params.clone();
        p[i] += h;
        let up = loss(&p);
        p[i] -= 2.0 * h;
        let fd = (up - loss(&p)) / (2.0 * h);
        // A ReLU kink within h of a sample makes the difference one-sided.
        assert!((fd - g[i]).abs() <= 1e-6 + 1e-5 * g[i].abs(), "param {i}: analytic {} vs fd {fd}", g[i]);
        checked += 1;
    }
    assert_eq!(checked, shape.params() as usize);
}

#[test]
fn encoding_at_twelve_levels_matches_f64() {
    let ctx = ctx_shared();
    let mlp = Mlp::new(ctx).unwrap();
    let shape = MlpShape { depth: 2, width: 4, skip: 1, levels_x: 12, levels_w: 12 };
    let mut rng = Rng(seed("mlp encode"));
    let mut samples: Vec<[f64; 6]> = vec![
        [1.0, -1.0, 0.0, 1.0, 0.0, 0.0],
        [0.999_999_9, -0.999_999_9, 1e-40, 0.0, -1.0, 0.0],
        [1.7, -2.3, 3.9, 0.0, 0.0, 1.0],
        [0.5, 0.25, -0.125, 0.577_350_3, 0.577_350_3, -0.577_350_3],
    ];
    samples.extend(random_samples(&mut rng, 60, 1.0));
    samples.extend(random_samples(&mut rng, 60, 4.0));
    let samples: Vec<[f64; 6]> = samples.iter().map(|s| s.map(|v| v as f32 as f64)).collect();
    let n = samples.len() as u32;
    let s = mlp.scratch(shape, n).unwrap();
    let flat: Vec<f32> = samples.iter().flat_map(|v| v.map(|c| c as f32)).collect();
    s.samples.upload(&flat).unwrap();
    let p = Buffer::from_slice(ctx, "params", &shape.init_params(1)).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    mlp.record_forward(&mut rec, &p, n, &s).unwrap();
    rec.submit_and_wait().unwrap();
    let in0 = s.first_input().download_range(0, (n * shape.dx()) as usize).unwrap();
    let cat = s.skip_input().download_range(0, (n * shape.cat_width()) as usize).unwrap();
    let mut worst = 0.0f64;
    for (i, smp) in samples.iter().enumerate() {
        let gx = mlp_ref::encode([smp[0], smp[1], smp[2]], 12);
        let gw = mlp_ref::encode([smp[3], smp[4], smp[5]], 12);
        let row = &cat[i * shape.cat_width() as usize..(i + 1) * shape.cat_width() as usize];
        for (f, r) in gx.iter().enumerate() {
            let a = in0[i * shape.dx() as usize + f] as f64;
            let b = row[shape.width as usize + f] as f64;
            // f32 sin/cos of a reduced argument: absolute error ~1e-6
            // (unreduced, sin(2^11 pi x) would be off by ~1e-3).
            assert!((a - r).abs() < 2e-5 && (b - r).abs() < 2e-5, "sample {i} gamma(x)[{f}]: gpu {a} / {b} vs f64 {r} (x = {:?})", &smp[..3]);
            worst = worst.max((a - r).abs());
        }
        for (f, r) in gw.iter().enumerate() {
            let b = row[(shape.width + shape.dx()) as usize + f] as f64;
            assert!((b - r).abs() < 2e-5, "sample {i} gamma(w)[{f}]: gpu {b} vs f64 {r}");
        }
    }
    eprintln!("encoding: worst absolute error {worst:.2e}");
    check_validation(ctx);
}

#[test]
fn saturated_and_extreme_inputs_stay_finite() {
    let mut rng = Rng(seed("mlp extreme"));
    let shape = MlpShape { depth: 3, width: 24, skip: 2, levels_x: 12, levels_w: 4 };
    // Large weights saturate the sigmoid head (outputs 0 and 1).
    let params: Vec<f32> = shape.init_params(rng.next_u64()).iter().map(|v| v * 40.0).collect();
    let samples: Vec<[f64; 6]> = vec![[1e4, -1e4, 3e7, 1.0, 0.0, 0.0], [1e-40, -1e-42, 0.0, 0.0, 1.0, 0.0], [-1.0, 1.0, -1.0, 0.0, 0.0, -1.0], [2.5, -7.75, 100.0, 0.6, 0.8, 0.0]];
    let samples: Vec<[f64; 6]> = samples.iter().map(|s| s.map(|v| v as f32 as f64)).collect();
    let d_out = vec![[1.0, -1.0, 0.5]; samples.len()];
    let run = gpu(shape, &params, &samples, &d_out);
    assert!(run.out.iter().all(|v| v.is_finite() && (0.0..=1.0).contains(v)), "outputs {:?}", run.out);
    assert!(run.out.iter().any(|&v| v == 0.0 || v == 1.0 || !(1e-6..=1.0 - 1e-6).contains(&v)), "the head did not saturate: {:?}", run.out);
    assert!(run.grads.iter().all(|v| v.is_finite()), "non-finite gradient");
}

#[test]
fn no_samples_and_bit_identical_reruns() {
    let mut rng = Rng(seed("mlp determinism"));
    let shape = MlpShape { depth: 4, width: 48, skip: 2, levels_x: 6, levels_w: 4 };
    let params = shape.init_params(rng.next_u64());
    let empty = gpu(shape, &params, &[], &[]);
    assert!(empty.grads.iter().all(|&v| v == 0.0), "no samples must give zero gradients");
    let samples = random_samples(&mut rng, 3001, 1.0);
    let d_out: Vec<[f64; 3]> = (0..samples.len()).map(|_| [0, 1, 2].map(|_| uni(&mut rng, -1.0, 1.0) as f32 as f64)).collect();
    let a = gpu(shape, &params, &samples, &d_out);
    let b = gpu(shape, &params, &samples, &d_out);
    assert!(a.out.iter().zip(&b.out).all(|(x, y)| x.to_bits() == y.to_bits()), "outputs differ between runs");
    assert!(a.grads.iter().zip(&b.grads).all(|(x, y)| x.to_bits() == y.to_bits()), "gradients differ between runs");
}

/// A network of `shape` with seeded parameters (uploaded as `p`) and
/// `cap` random samples (flattened as the scratch holds them), for the
/// tests of the GPU-count paths; `rng` continues the seeded stream.
struct Counted {
    mlp: Mlp,
    params: Vec<f32>,
    p: Buffer<f32>,
    flat: Vec<f32>,
    rng: Rng,
}

fn counted(name: &str, shape: MlpShape, cap: u32, extent: f64) -> Counted {
    let ctx = ctx_shared();
    let mut rng = Rng(seed(name));
    let params = shape.init_params(rng.next_u64());
    let samples = random_samples(&mut rng, cap as usize, extent);
    let flat: Vec<f32> = samples.iter().flat_map(|v| v.map(|c| c as f32)).collect();
    Counted { mlp: Mlp::new(ctx).unwrap(), p: Buffer::from_slice(ctx, "params", &params).unwrap(), params, flat, rng }
}

/// The forward with the sample count read on the GPU (the embedded light
/// field): the first `count` outputs bit-equal the host-count forward's,
/// nothing past the count is written, a count past the capacity is
/// clamped to it, and a count of 0 writes nothing. The workgroups follow
/// the count, not the capacity: none for 0, one row of them for 1, the
/// same for counts past the capacity as for the capacity.
#[test]
fn forward_with_a_gpu_count_matches_and_stops_at_it() {
    let ctx = ctx_shared();
    let cap = 700u32;
    let shape = MlpShape { depth: 4, width: 48, skip: 2, levels_x: 6, levels_w: 4 };
    let Counted { mlp, p, flat, .. } = counted("mlp counted", shape, cap, 1.5);
    let host = {
        let s = mlp.scratch(shape, cap).unwrap();
        s.samples.upload(&flat).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        mlp.record_forward(&mut rec, &p, cap, &s).unwrap();
        rec.submit_and_wait().unwrap();
        s.out.download_range(0, (cap * OUT) as usize).unwrap()
    };
    const SENTINEL: f32 = -7.25;
    let mut rows_launched = Vec::new();
    for count in [0u32, 1, 63, 64, 65, 333, cap, cap + 500] {
        let s = mlp.scratch(shape, cap).unwrap();
        s.samples.upload(&flat).unwrap();
        s.out.upload(&vec![SENTINEL; s.out.len()]).unwrap();
        let c = Buffer::from_slice(ctx, "count", &[count]).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        mlp.record_forward_counted(&mut rec, &p, &c, &s).unwrap();
        rec.submit_and_wait().unwrap();
        let out = s.out.download_range(0, (cap * OUT) as usize).unwrap();
        let k = (count.min(cap) * OUT) as usize;
        assert!(out[..k].iter().zip(&host[..k]).all(|(a, b)| a.to_bits() == b.to_bits()), "count {count}: outputs differ from the host-count forward");
        assert!(out[k..].iter().all(|&v| v == SENTINEL), "count {count}: wrote past the count");
        rows_launched.push(s.last_counted_grid().unwrap()[1]);
    }
    let [zero, one, .., full, past] = rows_launched[..] else { unreachable!() };
    assert!(zero == 0 && one == 1 && past == full, "workgroup rows launched for counts 0, 1, ..., cap, past it: {rows_launched:?}");
    assert!(rows_launched.windows(2).all(|w| w[0] <= w[1]) && full > 1, "workgroup rows launched must grow with the count: {rows_launched:?}");
    check_validation(ctx);
}

/// The backward with the sample count read on the GPU (one submission per
/// Stage III step): for counts that give one weight-gradient chunk, a
/// partial last chunk, exact chunk multiples and the largest splits, the
/// gradients are bit-identical to the host-count backward on the same
/// samples (same chunks, same summation order), and a count of 0 gives
/// zero gradients. Samples past the count hold garbage that must not leak.
#[test]
fn backward_with_a_gpu_count_is_bit_identical_to_the_host_count() {
    let ctx = ctx_shared();
    let cap = 5000u32;
    let shape = MlpShape { depth: 3, width: 40, skip: 2, levels_x: 4, levels_w: 2 };
    let Counted { mlp, flat, params, mut rng, .. } = counted("mlp counted backward", shape, cap, 1.2);
    let d_all: Vec<f32> = (0..OUT * cap).map(|_| uni(&mut rng, -1.0, 1.0) as f32).collect();
    // Host count: a scratch of exactly `count` samples; GPU count: the
    // full capacity, the samples past the count as well.
    let grads = |count: u32, counted: bool| on_kernel(mlp.gemm(), shape, &params, &flat, &d_all, count, counted.then_some(cap)).1;
    for count in [0u32, 1, 255, 256, 257, 1000, 4095, 4096, 4097, cap] {
        let (chunk, chunks) = weight_chunks(count);
        let host = grads(count, false);
        let gpu = grads(count, true);
        assert!(gpu.iter().all(|&b| f32::from_bits(b).is_finite()), "count {count}: non-finite gradient");
        let diff = host.iter().zip(&gpu).filter(|(a, b)| a != b).count();
        assert_eq!(diff, 0, "count {count} ({chunks} chunks of {chunk}): {diff} gradients differ from the host-count backward");
        if count == 0 {
            assert!(gpu.iter().all(|&b| f32::from_bits(b) == 0.0), "no samples must give zero gradients");
        }
    }
    check_validation(ctx);
}

/// Forward and backward of `n` samples on one GEMM kernel; with `cap`, the
/// GPU-count path on a scratch of `cap` samples (count `n`). Outputs and
/// gradients as bits.
fn on_kernel(gemm: Gemm, shape: MlpShape, params: &[f32], flat: &[f32], d_out: &[f32], n: u32, cap: Option<u32>) -> (Vec<u32>, Vec<u32>) {
    let ctx = ctx_shared();
    let mlp = Mlp::with_gemm(ctx, gemm).unwrap();
    assert_eq!(mlp.gemm(), gemm);
    let k = cap.unwrap_or(n);
    let s = mlp.scratch(shape, k.max(1)).unwrap();
    if k > 0 {
        s.samples.upload(&flat[..6 * k as usize]).unwrap();
    }
    let p = Buffer::from_slice(ctx, "params", params).unwrap();
    let d = Buffer::from_slice(ctx, "d_out", d_out).unwrap();
    let g = Buffer::from_slice(ctx, "grads", &vec![f32::NAN; params.len()]).unwrap();
    let c = Buffer::from_slice(ctx, "count", &[n]).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    if cap.is_some() {
        mlp.record_forward_counted(&mut rec, &p, &c, &s).unwrap();
        mlp.record_backward_counted(&mut rec, &p, &c, &d, &g, &s).unwrap();
    } else {
        mlp.record_forward(&mut rec, &p, n, &s).unwrap();
        mlp.record_backward(&mut rec, &p, n, &d, &g, &s).unwrap();
    }
    rec.submit_and_wait().unwrap();
    let out = if n > 0 { s.out.download_range(0, (n * OUT) as usize).unwrap() } else { Vec::new() };
    let bits = |v: Vec<f32>| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    (bits(out), bits(g.download().unwrap()))
}

/// The tiled kernel (GPUs), the row kernel (CPU devices) and the fused
/// kernels sum every element in the same order: their outputs and
/// gradients are the same bits, with host and GPU counts, on products
/// narrower and wider than every tile, column block and fused block, one
/// weight chunk and many, and the paper network (the fused kernels' widest
/// plan). (The other tests here run the kernel this device prefers.)
#[test]
fn tiled_row_and_fused_kernels_are_bit_identical() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("mlp kernels"));
    let cases = [
        (SMALL, 37),
        (MlpShape::SMALL, 1000),
        (MlpShape { depth: 4, width: 40, skip: 2, levels_x: 6, levels_w: 4 }, 2000),
        (MlpShape { depth: 3, width: 130, skip: 2, levels_x: 4, levels_w: 3 }, 300),
        (MlpShape::PAPER, 70),
    ];
    for (shape, n) in cases {
        let params = shape.init_params(rng.next_u64());
        let cap = n + 37;
        let flat: Vec<f32> = random_samples(&mut rng, cap as usize, 1.2).iter().flat_map(|v| v.map(|c| c as f32)).collect();
        let d_out: Vec<f32> = (0..OUT * cap).map(|_| uni(&mut rng, -1.0, 1.0) as f32).collect();
        for counted in [None, Some(cap)] {
            let (out_t, g_t) = on_kernel(Gemm::Tiled, shape, &params, &flat, &d_out, n, counted);
            assert!(g_t.iter().all(|&b| f32::from_bits(b).is_finite()), "{shape:?}: non-finite gradient");
            for other in [Gemm::Rows, Gemm::Fused] {
                let (out_o, g_o) = on_kernel(other, shape, &params, &flat, &d_out, n, counted);
                let diff = |a: &[u32], b: &[u32]| a.iter().zip(b).filter(|(x, y)| x != y).count();
                assert_eq!(diff(&out_t, &out_o), 0, "{shape:?} n={n} counted={counted:?}: {other:?} outputs differ from the tiled kernel's");
                assert_eq!(diff(&g_t, &g_o), 0, "{shape:?} n={n} counted={counted:?}: {other:?} gradients differ from the tiled kernel's");
            }
        }
    }
    assert!(Gemm::parse("rows").is_ok() && Gemm::parse("fused").is_ok() && Gemm::parse("tiles").is_err());
    check_validation(ctx);
}

/// The fused kernels refuse a layer wider than they take, naming the
/// width and the way out, and plan the paper network within lavapipe's
/// 32 KiB of shared memory (the bit-identity test above runs it).
#[test]
fn fused_kernels_refuse_what_they_cannot_hold() {
    let ctx = ctx_shared();
    let mlp = Mlp::with_gemm(ctx, Gemm::Fused).unwrap();
    let wide = MlpShape { depth: 2, width: tgs_pipelines::mlp::FUSED_MAX_WIDTH + 1, skip: 1, levels_x: 2, levels_w: 1 };
    let err = format!("{:#}", mlp.scratch(wide, 16).err().expect("a layer wider than the fused kernels take"));
    assert!(err.contains("257") && err.contains("TGS_MLP_GEMM"), "{err}");
    assert!(mlp.scratch(MlpShape::PAPER, 16).is_ok());
    // The layer-by-layer kernels take it.
    assert!(Mlp::with_gemm(ctx, Gemm::Tiled).unwrap().scratch(wide, 16).is_ok());
    check_validation(ctx);
}

/// The fused kernels against the f64 reference on their own (the other
/// reference tests run the kernel the device prefers): the small network
/// at 1 sample, either side of its 32-sample block and two blocks, a
/// network narrower than one column block, and the paper network either
/// side of its block (16 samples within lavapipe's 32 KiB); no samples
/// give zero gradients; reruns are the same bits; the GPU-count path at
/// its capacity is the tiled kernel's, bit for bit.
#[test]
fn fused_kernels_match_reference() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("mlp fused"));
    let fused = Some(Gemm::Fused);
    for n in [1, 31, 32, 33, 64] {
        check_network_on(fused, MlpShape::SMALL, n, 1.0, &mut rng);
    }
    check_network_on(fused, SMALL, 37, 1.0, &mut rng);
    for n in [15, 17] {
        check_network_on(fused, MlpShape::PAPER, n, 1.0, &mut rng);
    }
    let shape = MlpShape::SMALL;
    let params = shape.init_params(rng.next_u64());
    let empty = gpu_on(fused, shape, &params, &[], &[]);
    assert!(empty.grads.iter().all(|&v| v == 0.0), "no samples must give zero gradients");
    let samples = random_samples(&mut rng, 100, 1.0);
    let d_out: Vec<[f64; 3]> = (0..samples.len()).map(|_| [0, 1, 2].map(|_| uni(&mut rng, -1.0, 1.0) as f32 as f64)).collect();
    let a = gpu_on(fused, shape, &params, &samples, &d_out);
    let b = gpu_on(fused, shape, &params, &samples, &d_out);
    assert!(a.out.iter().zip(&b.out).all(|(x, y)| x.to_bits() == y.to_bits()), "fused outputs differ between runs");
    assert!(a.grads.iter().zip(&b.grads).all(|(x, y)| x.to_bits() == y.to_bits()), "fused gradients differ between runs");
    let flat: Vec<f32> = samples.iter().flat_map(|v| v.map(|c| c as f32)).collect();
    let d: Vec<f32> = d_out.iter().flat_map(|v| v.map(|c| c as f32)).collect();
    let n = samples.len() as u32;
    assert_eq!(on_kernel(Gemm::Fused, shape, &params, &flat, &d, n, Some(n)), on_kernel(Gemm::Tiled, shape, &params, &flat, &d, n, Some(n)), "the GPU count at capacity");
    check_validation(ctx);
}
