//! The high-frequency loss (pipelines/src/train/hf.rs) against its f64
//! reference (tests/src/loss_ref.rs): the percentile by radix select on
//! random errors, ties, all-equal errors, one pixel, p = 0 and p = 1,
//! sizes not a multiple of the workgroup; the gradient added to what the
//! buffer held; the reference's gradient against central differences away
//! from the threshold; bit-identical reruns.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::HfLoss;
use tgs_tests::loss_ref::hf_loss;
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

fn uni(rng: &mut Rng) -> f32 {
    (rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32
}

/// A render and a target of `n` random RGB pixels (planar).
fn random_pair(rng: &mut Rng, n: usize) -> (Vec<f32>, Vec<f32>) {
    let x = (0..3 * n).map(|_| uni(rng)).collect();
    let y = (0..3 * n).map(|_| uni(rng)).collect();
    (x, y)
}

struct Out {
    tau: f32,
    count: u32,
    mean: f64,
    grad: Vec<f32>,
}

fn gpu(x: &[f32], y: &[f32], n: usize, pct: f32, weight: f32, base: &[f32]) -> Out {
    let ctx = ctx_shared();
    let hf = HfLoss::new(ctx).unwrap();
    let s = hf.stats().unwrap();
    let xb = Buffer::from_slice(ctx, "render", x).unwrap();
    let yb = Buffer::from_slice(ctx, "target", y).unwrap();
    let gb = Buffer::from_slice(ctx, "grad", base).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    hf.record(&mut rec, tgs_pipelines::LossIo { render: &xb, target: &yb, grad: &gb }, n as u32, pct, weight, &s).unwrap();
    rec.submit_and_wait().unwrap();
    let (tau, count, mean) = s.values().unwrap();
    let out = Out { tau, count, mean, grad: gb.download().unwrap() };
    check_validation(ctx);
    out
}

fn check(x: &[f32], y: &[f32], n: usize, pct: f32, what: &str) {
    let weight = 0.1f32;
    let base: Vec<f32> = (0..3 * n).map(|i| (i % 7) as f32 * 0.01).collect();
    let got = gpu(x, y, n, pct, weight, &base);
    let (tau, count, mean, g) = hf_loss(x, y, n, pct as f64);
    assert_eq!(got.tau.to_bits(), tau.to_bits(), "{what}: tau {} vs {tau}", got.tau);
    assert_eq!(got.count as usize, count, "{what}: count");
    assert!((got.mean - mean).abs() <= 1e-5 * mean.max(1e-6), "{what}: mean {} vs {mean}", got.mean);
    for i in 0..3 * n {
        let want = base[i] as f64 + weight as f64 * g[i];
        assert!((got.grad[i] as f64 - want).abs() <= 1e-6 * (1.0 + want.abs()), "{what}: gradient {i}: {} vs {want}", got.grad[i]);
    }
}

#[test]
fn percentile_and_gradient_match_reference() {
    let mut rng = Rng(seed("hf"));
    for (n, pct) in [(1usize, 0.9f32), (7, 0.9), (257, 0.9), (4099, 0.9), (1000, 0.0), (1000, 1.0), (999, 0.5), (40_000, 0.95)] {
        let (x, y) = random_pair(&mut rng, n);
        check(&x, &y, n, pct, &format!("random n={n} p={pct}"));
    }
    // Ties: errors on a coarse grid (many pixels share the percentile value).
    let n = 3001;
    let x: Vec<f32> = (0..3 * n).map(|_| (rng.below(5) as f32) * 0.25).collect();
    let y = vec![0.0; 3 * n];
    check(&x, &y, n, 0.9, "ties");
    // All equal, and all zero (every pixel selected; zero gradient).
    let x = vec![0.75; 3 * 513];
    check(&x, &vec![0.25; 3 * 513], 513, 0.9, "all equal");
    check(&x, &x, 513, 0.9, "all zero");
}

#[test]
fn reference_gradient_matches_finite_differences() {
    let mut rng = Rng(seed("hf fd"));
    let n = 200;
    let (x, y) = random_pair(&mut rng, n);
    let (tau, _, _, g) = hf_loss(&x, &y, n, 0.9);
    let e = |i: usize| (x[i] - y[i]).abs() + (x[n + i] - y[n + i]).abs() + (x[2 * n + i] - y[2 * n + i]).abs();
    let h = 1e-3f32;
    let mut checked = 0;
    for i in 0..n {
        // Away from the threshold and from |x - y| = 0 the selection does not change.
        if (e(i) - tau).abs() < 4.0 * h || (0..3).any(|c| (x[c * n + i] - y[c * n + i]).abs() < 2.0 * h) {
            continue;
        }
        for c in 0..3 {
            let mut xp = x.clone();
            xp[c * n + i] += h;
            let mut xm = x.clone();
            xm[c * n + i] -= h;
            let fd = (hf_loss(&xp, &y, n, 0.9).2 - hf_loss(&xm, &y, n, 0.9).2) / (2.0 * h as f64);
            assert!((fd - g[c * n + i]).abs() < 1e-4, "pixel {i} channel {c}: analytic {} vs fd {fd}", g[c * n + i]);
            checked += 1;
        }
    }
    assert!(checked > 300, "only {checked} checks");
}

#[test]
fn reruns_are_bit_identical() {
    let mut rng = Rng(seed("hf determinism"));
    let n = 20_001;
    let (x, y) = random_pair(&mut rng, n);
    let base = vec![0.0; 3 * n];
    let a = gpu(&x, &y, n, 0.9, 0.1, &base);
    let b = gpu(&x, &y, n, 0.9, 0.1, &base);
    assert_eq!((a.tau.to_bits(), a.count, a.mean.to_bits()), (b.tau.to_bits(), b.count, b.mean.to_bits()));
    assert!(a.grad.iter().zip(&b.grad).all(|(p, q)| p.to_bits() == q.to_bits()));
}
