//! Stage III's deferred kernels against the f64 reference
//! (tests/src/lightfield_ref.rs): the compacted sample list (ranks, count,
//! x_refl and w_r; no pixel and every pixel evaluated; a pixel without a
//! normal), the composite and its backward with and without Schlick
//! (grazing and head-on views, no coverage, unevaluated pixels showing
//! the scattering colour alone), the
//! reference's gradient against central differences, and the material
//! sigmoid with its gradient.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::lightfield::{CompositeGrads, CompositeInputs};
use tgs_pipelines::lightfield::{LightFieldShading, ShadeParams, CHANNELS};
use tgs_pipelines::{Camera, Plane};
use tgs_tests::lightfield_ref::{self as lr, Cam, ReflPixel};
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

fn uni(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

fn camera(w: u32, h: u32) -> Camera {
    Camera::look_at([0.4, 1.1, 3.5], [0.1, -0.2, 0.0], [0.0, 1.0, 0.0], 0.9, w, h)
}

fn cam64(c: &Camera) -> Cam {
    Cam { rot: c.world_to_view.map(|r| r.map(|v| v as f64)), fx: c.fx as f64, fy: c.fy as f64, cx: c.cx as f64, cy: c.cy as f64 }
}

const SHADE: ShadeParams = ShadeParams { centre: [0.1, -0.3, 0.2], half_extent: [1.5, 0.75, 2.0], threshold: 0.05, schlick: true };

/// Random pixels (values already f32) with the special ones at the front:
/// no coverage, no normal, a grazing normal, R exactly at the threshold.
fn pixels(rng: &mut Rng, cam: &Camera, r_lo: f64) -> Vec<ReflPixel> {
    let n = (cam.width * cam.height) as usize;
    let f = |v: f64| v as f32 as f64;
    (0..n)
        .map(|i| {
            let alpha = f(uni(rng, 0.2, 1.0));
            let k = uni(rng, 0.3, 1.0) * alpha;
            let mut p = ReflPixel {
                f0s: [0, 1, 2].map(|_| f(uni(rng, 0.0, alpha))),
                r: f(uni(rng, r_lo, alpha)),
                alpha,
                depth: f(alpha * uni(rng, 1.0, 4.0)),
                normal: [f(uni(rng, -0.5, 0.5) * k), f(uni(rng, -0.5, 0.5) * k), f(-k)],
            };
            match i {
                0 => p = ReflPixel { f0s: [0.0; 3], r: 0.0, alpha: 0.0, depth: 0.0, normal: [0.0; 3] },
                1 => p.normal = [0.0; 3],
                2 => {
                    let (x, y) = ((i % cam.width as usize) as f64, (i / cam.width as usize) as f64);
                    let ray = [(x - cam.cx as f64) / cam.fx as f64, (y - cam.cy as f64) / cam.fy as f64, 1.0];
                    p.normal = [f(ray[1]), f(-ray[0]), 0.0];
                }
                3 => p.r = SHADE.threshold as f64,
                _ => {}
            }
            p
        })
        .collect()
}

fn planes(px: &[ReflPixel]) -> Vec<f32> {
    let n = px.len();
    let mut out = vec![0f32; Plane::count(CHANNELS) as usize * n];
    for (i, p) in px.iter().enumerate() {
        let mut set = |pl: u32, v: f64| out[pl as usize * n + i] = v as f32;
        for c in 0..3 {
            set(c, p.f0s[c as usize]);
        }
        set(3, p.r);
        set(Plane::Alpha.index(CHANNELS), p.alpha);
        set(Plane::Depth.index(CHANNELS), p.depth);
        for k in 0..3 {
            set(Plane::Normal(k).index(CHANNELS), p.normal[k as usize]);
        }
        set(Plane::Median.index(CHANNELS), 2.0);
    }
    out
}

struct Samples {
    sample_of: Vec<u32>,
    count: u32,
    samples: Vec<f32>,
}

fn gpu_samples(cam: &Camera, refl: &[f32], p: &ShadeParams) -> Samples {
    gpu_samples_cap(cam, refl, p, (cam.width * cam.height) as usize)
}

/// With room for `cap` samples.
fn gpu_samples_cap(cam: &Camera, refl: &[f32], p: &ShadeParams, cap: usize) -> Samples {
    let ctx = ctx_shared();
    let lf = LightFieldShading::new(ctx).unwrap();
    let s = lf.sample_scratch(cam.width, cam.height).unwrap();
    let rb = Buffer::from_slice(ctx, "refl", refl).unwrap();
    let samples = Buffer::uninit(ctx, "samples", 6 * cap).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    lf.record_samples(&mut rec, cam, p, &rb, &s, &samples).unwrap();
    rec.submit_and_wait().unwrap();
    let count = s.count.download().unwrap()[0];
    let kept = (count as usize).min(cap);
    let out = Samples { sample_of: s.sample_of.download().unwrap(), count, samples: if kept > 0 { samples.download_range(0, 6 * kept).unwrap() } else { vec![] } };
    check_validation(ctx);
    out
}

#[test]
fn sample_list_matches_reference() {
    let mut rng = Rng(seed("lf samples"));
    for (w, h) in [(13u32, 7u32), (1, 1), (40, 30)] {
        let cam = camera(w, h);
        let c = cam64(&cam);
        let px = pixels(&mut rng, &cam, 0.0);
        let got = gpu_samples(&cam, &planes(&px), &SHADE);
        let mut rank = 0u32;
        for (i, p) in px.iter().enumerate() {
            let (x, y) = ((i % w as usize) as f64, (i / w as usize) as f64);
            if p.r as f32 > SHADE.threshold {
                assert_eq!(got.sample_of[i], rank, "{w}x{h} pixel {i}: rank");
                let r = lr::sample(&c, x, y, p, SHADE.centre.map(|v| v as f64), SHADE.half_extent.map(|v| v as f64));
                let g = &got.samples[6 * rank as usize..6 * rank as usize + 6];
                for k in 0..6 {
                    assert!((g[k] as f64 - r[k]).abs() < 2e-5 * (1.0 + r[k].abs()), "{w}x{h} pixel {i} sample[{k}]: gpu {} vs f64 {} ({p:?})", g[k], r[k]);
                }
                let wl = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
                assert!((wl - 1.0).abs() < 1e-9);
                rank += 1;
            } else {
                assert_eq!(got.sample_of[i], u32::MAX, "{w}x{h} pixel {i} (R = {}) must not be evaluated", p.r);
            }
        }
        assert_eq!(got.count, rank, "{w}x{h}: count");
    }
}

#[test]
fn sample_list_when_no_pixel_and_every_pixel_reflects() {
    let mut rng = Rng(seed("lf all none"));
    let cam = camera(17, 9);
    let mut px = pixels(&mut rng, &cam, 0.0);
    for p in px.iter_mut() {
        p.r = 0.01;
    }
    let none = gpu_samples(&cam, &planes(&px), &SHADE);
    assert_eq!(none.count, 0);
    assert!(none.sample_of.iter().all(|&s| s == u32::MAX));
    for p in px.iter_mut() {
        p.alpha = 0.9;
        p.r = 0.5;
    }
    let all = gpu_samples(&cam, &planes(&px), &SHADE);
    assert_eq!(all.count, 17 * 9);
    assert!(all.sample_of.iter().enumerate().all(|(i, &s)| s == i as u32));
    assert!(all.samples.iter().all(|v| v.is_finite()));
    // A list with room for 10: the count still says how many reflect (the
    // caller refuses the view), ranks past the room are not evaluated.
    let capped = gpu_samples_cap(&cam, &planes(&px), &SHADE, 10);
    assert_eq!(capped.count, 17 * 9);
    assert!(capped.sample_of.iter().enumerate().all(|(i, &s)| if i < 10 { s == i as u32 } else { s == u32::MAX }));
    assert_eq!(&capped.samples[..], &all.samples[..60]);
}

#[test]
fn composite_matches_reference_and_finite_differences() {
    let ctx = ctx_shared();
    let lf = LightFieldShading::new(ctx).unwrap();
    let mut rng = Rng(seed("lf composite"));
    for schlick in [true, false] {
        for (w, h) in [(11u32, 6u32), (1, 1)] {
            let cam = camera(w, h);
            let c = cam64(&cam);
            let n = (w * h) as usize;
            let p = ShadeParams { schlick, ..SHADE };
            let px = pixels(&mut rng, &cam, 0.0);
            let refl = planes(&px);
            let s = lf.sample_scratch(w, h).unwrap();
            let rb = Buffer::from_slice(ctx, "refl", &refl).unwrap();
            let samples = Buffer::uninit(ctx, "samples", 6 * n).unwrap();
            let scat: Vec<f32> = (0..3 * n).map(|_| uni(&mut rng, 0.0, 1.0) as f32).collect();
            let phi: Vec<f32> = (0..3 * n).map(|_| uni(&mut rng, 0.0, 1.0) as f32).collect();
            let g: Vec<f32> = (0..10 * n).map(|_| uni(&mut rng, -1.0, 1.0) as f32).collect();
            // A penalty r_prior * R per pixel: its gradient joins dR at
            // every pixel, evaluated or not.
            let r_prior = uni(&mut rng, 0.1, 0.5) as f32;
            let sb = Buffer::from_slice(ctx, "scat", &scat).unwrap();
            let pb = Buffer::from_slice(ctx, "phi", &phi).unwrap();
            let gb = Buffer::from_slice(ctx, "loss_grad", &g).unwrap();
            let loss_in = Buffer::uninit(ctx, "loss_in", 10 * n).unwrap();
            let dphi = Buffer::from_slice(ctx, "dphi", &vec![f32::NAN; 3 * n]).unwrap();
            let rg = Buffer::uninit(ctx, "refl_grad", Plane::count(CHANNELS) as usize * n).unwrap();
            let sg = Buffer::uninit(ctx, "scat_grad", 3 * n).unwrap();
            let mut rec = Recorder::new(ctx).unwrap();
            lf.record_samples(&mut rec, &cam, &p, &rb, &s, &samples).unwrap();
            let inputs = CompositeInputs { scat: &sb, refl: &rb, samples: &s, phi: &pb };
            lf.record_composite(&mut rec, &cam, &p, &inputs, &loss_in).unwrap();
            let grads = CompositeGrads { loss_grad: &gb, d_phi: &dphi, refl_grad: &rg, scat_grad: Some(&sg) };
            lf.record_composite_backward(&mut rec, &cam, &p, &inputs, &grads, r_prior).unwrap();
            rec.submit_and_wait().unwrap();
            let (li, dp, rgv, sgv, so) = (loss_in.download().unwrap(), dphi.download().unwrap(), rg.download().unwrap(), sg.download().unwrap(), s.sample_of.download().unwrap());
            for (i, px_i) in px.iter().enumerate() {
                let (x, y) = ((i % w as usize) as f64, (i / w as usize) as f64);
                let m = lr::schlick_m(&c, x, y, px_i, schlick);
                let sm = so[i];
                let evaluated = (sm != u32::MAX).then(|| [0, 1, 2].map(|k| phi[3 * sm as usize + k] as f64));
                let ph = evaluated.unwrap_or([0.0; 3]);
                let sc = [0, 1, 2].map(|k| scat[k * n + i] as f64);
                let gi = [0, 1, 2].map(|k| g[k * n + i] as f64);
                let want = lr::composite_at(px_i, m, sc, evaluated);
                let tol = |r: f64| 2e-5 * (1.0 + r.abs());
                for k in 0..3 {
                    let got = li[k * n + i] as f64;
                    assert!((got - want[k]).abs() < tol(want[k]), "schlick {schlick} pixel {i} I[{k}]: {got} vs {}", want[k]);
                }
                // The reference's gradient of the evaluated form (a random
                // Phi where the pixel was not evaluated) against central
                // differences of g . I.
                let (e_phi, e_f0s, e_r, _) = lr::composite_grad(px_i, m, sc, ph, gi);
                let gi_dot = |q: &ReflPixel, ph: [f64; 3], sc: [f64; 3]| -> f64 { lr::composite(q, m, sc, ph).iter().zip(gi).map(|(a, b)| a * b).sum() };
                let hh = 1e-6;
                let fd_r = {
                    let (mut a, mut b) = (*px_i, *px_i);
                    a.r += hh;
                    b.r -= hh;
                    (gi_dot(&a, ph, sc) - gi_dot(&b, ph, sc)) / (2.0 * hh)
                };
                assert!((fd_r - e_r).abs() < 1e-6 * (1.0 + e_r.abs()), "reference dR {e_r} vs fd {fd_r}");
                for k in 0..3 {
                    let (mut a, mut b) = (*px_i, *px_i);
                    a.f0s[k] += hh;
                    b.f0s[k] -= hh;
                    let fd = (gi_dot(&a, ph, sc) - gi_dot(&b, ph, sc)) / (2.0 * hh);
                    assert!((fd - e_f0s[k]).abs() < 1e-4 * (1.0 + e_f0s[k].abs()), "reference dF0s {} vs fd {fd}", e_f0s[k]);
                    let (mut pa, mut pb2) = (ph, ph);
                    pa[k] += hh;
                    pb2[k] -= hh;
                    let fd = (gi_dot(px_i, pa, sc) - gi_dot(px_i, pb2, sc)) / (2.0 * hh);
                    assert!((fd - e_phi[k]).abs() < 1e-6 * (1.0 + e_phi[k].abs()));
                }
                // What the GPU must give: the evaluated form, or at a pixel
                // without Phi I = S (gradient only to S).
                let (d_phi, d_f0s, d_r, d_s) = lr::composite_grad_at(px_i, m, sc, evaluated, gi);
                if evaluated.is_none() {
                    assert!(d_r == 0.0 && d_f0s == [0.0; 3] && d_s == gi);
                }
                for k in 0..3 {
                    let got = rgv[k * n + i] as f64;
                    assert!((got - d_f0s[k]).abs() < tol(d_f0s[k]), "schlick {schlick} pixel {i} dF0s[{k}]: {got} vs {}", d_f0s[k]);
                    let got = sgv[k * n + i] as f64;
                    assert!((got - d_s[k]).abs() < tol(d_s[k]), "pixel {i} dS[{k}]");
                    if sm != u32::MAX {
                        let got = dp[3 * sm as usize + k] as f64;
                        assert!((got - d_phi[k]).abs() < tol(d_phi[k]), "pixel {i} dPhi[{k}]: {got} vs {}", d_phi[k]);
                    }
                }
                let got = rgv[3 * n + i] as f64;
                let d_r = d_r + r_prior as f64;
                assert!((got - d_r).abs() < tol(d_r), "schlick {schlick} pixel {i} dR: {got} vs {d_r}");
                for k in 4..Plane::count(CHANNELS) as usize {
                    assert_eq!(rgv[k * n + i], 0.0, "frozen geometry planes get no gradient");
                }
            }
            // Samples nobody evaluates keep their (NaN) value: one writer per sample.
            let count = s.count.download().unwrap()[0] as usize;
            assert!(dp[..3 * count].iter().all(|v| v.is_finite()));
            assert!(li.iter().chain(&rgv).chain(&sgv).all(|v| v.is_finite()), "non-finite composite values");
        }
    }
    check_validation(ctx);
}

#[test]
fn material_sigmoid_and_gradient() {
    let ctx = ctx_shared();
    let lf = LightFieldShading::new(ctx).unwrap();
    let mut rng = Rng(seed("lf material"));
    let n = 37u32;
    let mut mat: Vec<f32> = (0..4 * n).map(|_| uni(&mut rng, -6.0, 6.0) as f32).collect();
    mat[0] = 80.0;
    mat[1] = -80.0;
    let df: Vec<f32> = (0..4 * n).map(|_| uni(&mut rng, -1.0, 1.0) as f32).collect();
    let mb = Buffer::from_slice(ctx, "mat", &mat).unwrap();
    let fb = Buffer::uninit(ctx, "feat", 4 * n as usize).unwrap();
    let dfb = Buffer::from_slice(ctx, "dfeat", &df).unwrap();
    let dmb = Buffer::uninit(ctx, "dmat", 4 * n as usize).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    lf.record_material(&mut rec, &mb, n, &fb).unwrap();
    lf.record_material_backward(&mut rec, &mb, n, &dfb, &dmb).unwrap();
    rec.submit_and_wait().unwrap();
    let (f, dm) = (fb.download().unwrap(), dmb.download().unwrap());
    for i in 0..(4 * n) as usize {
        let s = 1.0 / (1.0 + (-(mat[i] as f64)).exp());
        assert!((f[i] as f64 - s).abs() < 1e-6, "feature {i}: {} vs {s}", f[i]);
        let d = df[i] as f64 * s * (1.0 - s);
        assert!((dm[i] as f64 - d).abs() < 1e-6 * (1.0 + d.abs()) && dm[i].is_finite(), "material gradient {i}: {} vs {d}", dm[i]);
    }
    check_validation(ctx);
}
