//! The GPU image loss against the CPU f64 reference: values, gradients of
//! every render plane against central finite differences, determinism, and
//! degenerate image sizes.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Camera, Features, ImageLoss, LossValues, LossWeights, Plane, Rasterizer};
use tgs_tests::loss_ref::{loss, LossInput};
use tgs_tests::Rng as Rng64;
use tgs_tests::{check_validation, ctx_shared, seed};

struct Case {
    inp: LossInput,
    planes: Vec<f64>,
}

fn camera(w: usize, h: usize) -> Camera {
    Camera {
        width: w as u32,
        height: h as u32,
        fx: 1.1 * w as f32,
        fy: 1.05 * w as f32,
        cx: 0.45 * w as f32,
        cy: 0.55 * h as f32,
        world_to_view: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
    }
}

fn case(rng: &mut Rng64, w: usize, h: usize, weights: &LossWeights) -> Case {
    let c = 3;
    let n = w * h;
    let cam = camera(w, h);
    let mut planes = vec![0.0; (c + 7) * n];
    for v in &mut planes[..c * n] {
        *v = rng.uniform(0.0, 1.0);
    }
    for i in 0..n {
        let (x, y) = ((i % w) as f64, (i / w) as f64);
        let empty = rng.uniform(0.0, 1.0) < 0.1;
        let a = if empty { 0.0 } else { rng.uniform(0.3, 1.0) };
        let z = 2.0 + 0.3 * (x / 3.0).sin() + 0.2 * y / h as f64 + rng.uniform(0.0, 0.05);
        planes[c * n + i] = a;
        planes[(c + 1) * n + i] = a * z;
        let d = [rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -1.0];
        let l = (d[0] * d[0] + d[1] * d[1] + 1.0f64).sqrt();
        for k in 0..3 {
            planes[(c + 2 + k) * n + i] = a * d[k] / l;
        }
        planes[(c + 5) * n + i] = z;
        planes[(c + 6) * n + i] = rng.uniform(0.0, 0.1);
    }
    let inp = LossInput {
        width: w,
        height: h,
        channels: c,
        fx: cam.fx as f64,
        fy: cam.fy as f64,
        cx: cam.cx as f64,
        cy: cam.cy as f64,
        ssim: weights.ssim as f64,
        normal: weights.normal as f64,
        dist: weights.dist as f64,
        target: (0..c * n).map(|_| rng.uniform(0.0, 1.0)).collect(),
    };
    // The L1 term has a kink where a colour equals its target: no colour
    // within 1e-4 of it, so that the central differences (step 1e-6) never
    // straddle it (a seed put one 7.6e-7 away, and the differences averaged
    // the two slopes there: relative error 5.5e-3 on a correct gradient).
    for (p, &t) in planes[..c * n].iter_mut().zip(&inp.target) {
        if (*p - t).abs() < 1e-4 {
            *p = if t < 0.5 { t + 1e-4 } else { t - 1e-4 };
        }
    }
    Case { inp, planes }
}

/// GPU loss: (gradient planes, values).
fn gpu(case: &Case, weights: &LossWeights) -> (Vec<f32>, LossValues) {
    let ctx = ctx_shared();
    let (w, h) = (case.inp.width as u32, case.inp.height as u32);
    let rast = Rasterizer::new(ctx, 3, Features::Plain).unwrap();
    let frame = rast.frame(w, h, 1, 1).unwrap();
    frame.out.upload(&case.planes.iter().map(|&v| v as f32).collect::<Vec<_>>()).unwrap();
    let target = Buffer::from_slice(ctx, "target", &case.inp.target.iter().map(|&v| v as f32).collect::<Vec<_>>()).unwrap();
    let lossk = ImageLoss::new(ctx).unwrap();
    let mut scratch = lossk.scratch(w, h, 3).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    lossk.record(&mut rec, &frame, &target, &camera(w as usize, h as usize), weights, &mut scratch).unwrap();
    rec.submit_and_wait().unwrap();
    check_validation(ctx);
    (frame.grad_out.download().unwrap(), scratch.values().unwrap())
}

fn rel(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>().sqrt();
    let n: f64 = b.iter().map(|y| y * y).sum::<f64>().sqrt();
    d / n.max(1e-30)
}

/// Central differences of the f64 reference over the first `len` plane entries.
fn central_differences(c: &Case, alpha_det: &[f64], len: usize) -> Vec<f64> {
    let eps = 1e-6;
    let mut fd = vec![0.0; len];
    let mut p = c.planes.clone();
    for i in 0..len {
        let v = p[i];
        p[i] = v + eps;
        let lp = loss(&c.inp, &p, alpha_det).0;
        p[i] = v - eps;
        let lm = loss(&c.inp, &p, alpha_det).0;
        p[i] = v;
        fd[i] = (lp - lm) / (2.0 * eps);
    }
    fd
}

#[test]
fn loss_values_and_gradients_match_the_reference() {
    let mut rng = Rng64(seed("loss_values_and_gradients_match_the_reference"));
    let weights = LossWeights { ssim: 0.2, normal: 0.05, dist: 0.1 };
    let (w, h) = (21, 13);
    let c = case(&mut rng, w, h, &weights);
    let n = w * h;
    let alpha_det: Vec<f64> = c.planes[3 * n..4 * n].to_vec();
    let (_, parts) = loss(&c.inp, &c.planes, &alpha_det);
    let (grad, vals) = gpu(&c, &weights);
    for (name, g, r) in [("l1", vals.l1, parts[0]), ("mse", vals.mse, parts[1]), ("ssim", vals.ssim, parts[2]), ("normal", vals.normal, parts[3])] {
        assert!((g - r).abs() <= 1e-5 * r.abs().max(1e-3), "{name}: GPU {g} vs reference {r}");
    }
    let fd = central_differences(&c, &alpha_det, c.planes.len());
    let g64: Vec<f64> = grad.iter().map(|&v| v as f64).collect();
    let groups = [("colour", 0, 3), ("alpha", 3, 4), ("depth", 4, 5), ("normal", 5, 8), ("median", 8, 9), ("distortion", 9, 10)];
    for (name, a, b) in groups {
        let (gs, fs) = (&g64[a * n..b * n], &fd[a * n..b * n]);
        if name == "median" {
            assert!(gs.iter().all(|&v| v == 0.0) && fs.iter().all(|v| v.abs() < 1e-9), "median depth has no loss gradient");
            continue;
        }
        let e = rel(gs, fs);
        eprintln!("{name}: relative gradient error {e:.2e}");
        assert!(e < 1e-3, "{name}: GPU gradient vs finite differences: relative error {e:.3e}");
    }
}

#[test]
fn loss_is_deterministic_and_normal_term_switches_off() {
    let mut rng = Rng64(seed("loss_is_deterministic_and_normal_term_switches_off"));
    let on = LossWeights { ssim: 0.2, normal: 0.05, dist: 0.0 };
    let c = case(&mut rng, 37, 19, &on);
    let (g1, v1) = gpu(&c, &on);
    let (g2, v2) = gpu(&c, &on);
    assert!(g1.iter().zip(&g2).all(|(a, b)| a.to_bits() == b.to_bits()), "gradients differ between identical runs");
    assert_eq!(v1, v2);
    let off = LossWeights { normal: 0.0, ..on };
    let (g3, v3) = gpu(&c, &off);
    let n = 37 * 19;
    for plane in [Plane::Alpha, Plane::Depth, Plane::Normal(0), Plane::Normal(1), Plane::Normal(2), Plane::Distortion] {
        let i = plane.index(3) as usize;
        assert!(g3[i * n..(i + 1) * n].iter().all(|&v| v == 0.0), "{plane:?}: gradient without normal/distortion terms");
    }
    assert!(v3.normal.is_nan());
    assert_eq!(&g1[..3 * n], &g3[..3 * n], "colour gradients must not depend on the normal term");
}

#[test]
fn tiny_images_give_finite_losses() {
    let mut rng = Rng64(seed("tiny_images_give_finite_losses"));
    let weights = LossWeights { ssim: 0.2, normal: 0.05, dist: 0.01 };
    // Images narrower or lower than the 11-tap window, or both: the blur's
    // valid tap ranges are clipped on both sides at once.
    for (w, h) in [(1, 1), (2, 1), (1, 5), (3, 3), (4, 14), (13, 2)] {
        let c = case(&mut rng, w, h, &weights);
        let n = w * h;
        let (grad, vals) = gpu(&c, &weights);
        assert!(grad.iter().all(|v| v.is_finite()), "{w}x{h}: non-finite gradient");
        let (_, parts) = loss(&c.inp, &c.planes, &c.planes[3 * n..4 * n]);
        let fd = central_differences(&c, &c.planes[3 * n..4 * n], 3 * n);
        let g64: Vec<f64> = grad[..3 * n].iter().map(|&v| v as f64).collect();
        let e = rel(&g64, &fd);
        assert!(e < 1e-3, "{w}x{h}: colour gradient vs finite differences: relative error {e:.3e}");
        assert!((vals.ssim - parts[2]).abs() < 1e-5, "{w}x{h}: SSIM {} vs {}", vals.ssim, parts[2]);
        assert!((vals.normal - parts[3]).abs() < 1e-6, "{w}x{h}: normal term {} vs {}", vals.normal, parts[3]);
    }
}
