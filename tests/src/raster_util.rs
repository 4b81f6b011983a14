//! Scenes, GPU runs and comparisons for the rasterizer tests.

use crate::raster_ref::{self, RefScene};
use crate::{ctx_shared, Rng};
use tgs_pipelines::{Camera, Features, Gaussians, HostGaussians, Plane, Rasterizer};

impl Rng {
    /// Uniform in [lo, hi).
    pub fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Parameters of a random scene.
pub struct SceneSpec {
    pub n: usize,
    pub channels: u32,
    pub features: Features,
    /// Half-size of the cube the means are drawn from (centred at the origin).
    pub extent: f64,
    pub log_scale: (f64, f64),
    pub opacity: (f64, f64),
}

impl SceneSpec {
    pub fn new(n: usize, channels: u32, features: Features) -> Self {
        SceneSpec { n, channels, features, extent: 1.0, log_scale: (-3.0, -1.2), opacity: (-1.5, 2.0) }
    }
}

/// A rasterizer test's start: the shared device, a rasterizer of three
/// channels at SH degree 3, and the random stream named for the test.
pub fn sh3_case(name: &str) -> (&'static std::sync::Arc<tgs_engine::Context>, Rasterizer, Rng) {
    let ctx = ctx_shared();
    (ctx, Rasterizer::new(ctx, 3, Features::Sh { degree: 3 }).unwrap(), Rng(crate::seed(name)))
}

/// A splat's normal t_w: the third column of the rotation of its
/// quaternion (r, x, y, z), normalised first.
pub fn splat_normal(q: [f32; 4]) -> [f64; 3] {
    let q = q.map(f64::from);
    let l = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [r, x, y, z] = q.map(|v| v / l);
    [2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y)]
}

pub fn random_quat(rng: &mut Rng) -> [f32; 4] {
    [0; 4].map(|_| rng.uniform(-1.0, 1.0) as f32)
}

pub fn random_scene(rng: &mut Rng, s: &SceneSpec) -> HostGaussians {
    let coeffs = s.features.coeffs();
    let mut h = HostGaussians::new(s.channels, coeffs);
    for _ in 0..s.n {
        let mean = [0; 3].map(|_| rng.uniform(-s.extent, s.extent) as f32);
        let ls = [0; 2].map(|_| rng.uniform(s.log_scale.0, s.log_scale.1) as f32);
        let q = random_quat(rng);
        let o = rng.uniform(s.opacity.0, s.opacity.1) as f32;
        let feats: Vec<f32> = (0..coeffs * s.channels)
            .map(|i| {
                let k = i / s.channels;
                let amp = if k == 0 { 1.0 } else { 0.3 };
                rng.uniform(-amp, amp) as f32
            })
            .collect();
        h.push(mean, ls, q, o, &feats);
    }
    h
}

/// The bit patterns of `v`, for bit-identity asserts.
pub fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

/// The parameter (or gradient) arrays of a set by name, in layout order.
pub fn named_arrays(g: &HostGaussians) -> [(&'static str, &[f32]); 5] {
    [("means", &g.means), ("log_scales", &g.log_scales), ("quats", &g.quats), ("opacity", &g.opacity), ("features", &g.features)]
}

/// A camera 4 units from the origin in a general pose.
pub fn default_camera(w: u32, h: u32) -> Camera {
    Camera::look_at([0.7, -0.5, -3.8], [0.05, 0.02, 0.0], [0.1, -1.0, 0.05], 0.9, w, h)
}

pub struct GpuRun {
    pub out: Vec<f32>,
    pub grads: Option<HostGaussians>,
    pub densify: Vec<f32>,
    pub intersections: u32,
    pub spans: u32,
    /// Tile rectangle of every Gaussian, and the tile side they count in.
    pub rects: Vec<[u32; 4]>,
    pub tile: u32,
}

/// Forward (and backward when `grad_out` is given) on the GPU.
pub fn gpu_run(rast: &Rasterizer, host: &HostGaussians, cam: &Camera, bg: &[f32], degree: u32, grad_out: Option<&[f32]>) -> GpuRun {
    let ctx = ctx_shared();
    let g = Gaussians::upload(ctx, host).unwrap();
    let mut frame = rast.frame(cam.width, cam.height, host.len() as u32, 1024).unwrap();
    rast.forward(&g, cam, bg, degree, &mut frame, false).unwrap();
    let out = frame.out.download().unwrap();
    let rects = frame.download_rects(host.len()).unwrap();
    let mut run = GpuRun { out, grads: None, densify: vec![], intersections: frame.last_intersections, spans: frame.spans, rects, tile: frame.tile };
    if let Some(go) = grad_out {
        frame.grad_out.upload(go).unwrap();
        let grads = Gaussians::zeros(ctx, g.n, g.channels, g.coeffs).unwrap();
        rast.backward(&g, &grads, degree, &frame, false).unwrap();
        run.grads = Some(grads.download().unwrap());
        run.densify = frame.densify.download_range(0, 2 * host.len()).unwrap();
    }
    run
}

/// Compare GPU and CPU planes over unambiguous pixels. Returns the worst
/// error relative to the pixel's tolerance (<= 1 passes) with a description,
/// the number of ambiguous pixels left out and the number of pixels whose
/// tolerance was widened. Panics on NaN/Inf on the GPU.
pub fn compare_forward(gpu: &[f32], cpu: &raster_ref::RefRender, channels: u32, pixels: usize) -> (f64, String, usize, usize) {
    let planes = Plane::count(channels) as usize;
    assert_eq!(gpu.len(), planes * pixels);
    let mut worst = (0.0f64, String::new());
    let (mut skipped, mut widened) = (0, 0);
    for i in 0..pixels {
        for p in 0..planes {
            let g = gpu[p * pixels + i];
            assert!(g.is_finite(), "GPU output plane {p} pixel {i} is {g}");
        }
        if cpu.ambiguous[i] {
            skipped += 1;
            continue;
        }
        let tol = cpu.tolerance[i];
        widened += (tol > raster_ref::ILL_CONDITIONED) as usize;
        for p in 0..planes {
            let g = gpu[p * pixels + i];
            let e = (g as f64 - cpu.planes[p * pixels + i]).abs();
            if e / tol > worst.0 {
                worst = (e / tol, format!("plane {p} pixel {i}: gpu {g} cpu {} (error {e:.2e}, tolerance {tol:.2e})", cpu.planes[p * pixels + i]));
            }
        }
    }
    (worst.0, worst.1, skipped, widened)
}

/// Forward on GPU and CPU: every unambiguous pixel within its tolerance
/// (1e-4 abs unless ill-conditioned), at most 1% of pixels ambiguous.
pub fn check_forward(rast: &Rasterizer, host: &HostGaussians, cam: &Camera, bg: &[f32], degree: u32, what: &str) -> GpuRun {
    check_forward_with(rast, host, cam, bg, degree, 0.01, what)
}

/// As [`check_forward`] with at most a fraction `max_ambiguous` of pixels
/// left out (dense piles of faint splats sit at the 1/255 cut more often).
pub fn check_forward_with(rast: &Rasterizer, host: &HostGaussians, cam: &Camera, bg: &[f32], degree: u32, max_ambiguous: f64, what: &str) -> GpuRun {
    let run = gpu_run(rast, host, cam, bg, degree, None);
    let scene = RefScene::from_host(host, rast.features() == Features::Plain);
    let bg64: Vec<f64> = bg.iter().map(|&v| v as f64).collect();
    let bad = raster_ref::rects_agree(&scene, cam, degree, &run.rects, run.tile);
    assert!(bad.is_empty(), "{what}: tile rectangles of Gaussians {bad:?} differ from the reference beyond rounding");
    let cpu = raster_ref::render_with_rects(&scene, cam, &bg64, degree, Some((&run.rects, run.tile)));
    let pixels = (cam.width * cam.height) as usize;
    let (err, at, skipped, widened) = compare_forward(&run.out, &cpu, rast.channels(), pixels);
    eprintln!("{what}: worst error/tolerance {err:.3} ({at}); {skipped} ambiguous and {widened} ill-conditioned pixels of {pixels}; {} intersections", run.intersections);
    assert!(err <= 1.0, "{what}: forward differs from the CPU reference: {at}");
    assert!(skipped as f64 <= max_ambiguous * pixels.max(100) as f64, "{what}: {skipped} of {pixels} pixels ambiguous");
    run
}

/// The scalar loss sum(weights * planes) on the CPU reference.
pub fn ref_loss(s: &RefScene, cam: &Camera, bg: &[f64], degree: u32, weights: &[f64]) -> f64 {
    let r = raster_ref::render(s, cam, bg, degree);
    r.planes.iter().zip(weights).map(|(p, w)| p * w).sum()
}

/// Gradient check: GPU backward of the loss sum(weights * planes) (random
/// weights; zero on ambiguous pixels and on severely ill-conditioned ones,
/// where a grazing hit makes the f32 gradient as inexact as the f32 forward;
/// see `raster_ref::GRADIENT_ILL_CONDITIONED`) against central finite differences of
/// the f64 reference. Metric per parameter group: ||g_gpu - g_fd|| / ||g_fd||
/// over the group's parameters, <= 1e-2. Parameters whose finite difference
/// is not stable between steps eps and eps/2 sit on a discontinuity (a
/// threshold crossed by the perturbation) and are left out and counted (at
/// most 2%). Groups whose gradient is exactly zero everywhere are reported
/// and must be in `zero_ok`.
#[allow(clippy::too_many_arguments)] // a test helper: the scene, the camera and the check's knobs
pub fn check_gradients(rast: &Rasterizer, host: &HostGaussians, cam: &Camera, bg: &[f32], degree: u32, rng: &mut Rng, zero_ok: &[&str], what: &str) {
    check_gradients_with(rast, host, cam, bg, degree, rng, zero_ok, 0.02, what)
}

/// As [`check_gradients`], allowing a fraction `max_unstable` of the
/// parameters to sit on a discontinuity (e.g. exactly equal depths).
#[allow(clippy::too_many_arguments)]
pub fn check_gradients_with(rast: &Rasterizer, host: &HostGaussians, cam: &Camera, bg: &[f32], degree: u32, rng: &mut Rng, zero_ok: &[&str], max_unstable: f64, what: &str) {
    let plain = rast.features() == Features::Plain;
    let base = RefScene::from_host(host, plain);
    let bg64: Vec<f64> = bg.iter().map(|&v| v as f64).collect();
    let cpu = raster_ref::render(&base, cam, &bg64, degree);
    let pixels = (cam.width * cam.height) as usize;
    let planes = Plane::count(rast.channels()) as usize;
    let mut weights = vec![0.0f64; planes * pixels];
    for p in 0..planes {
        for i in 0..pixels {
            if cpu.gradient_checkable(i) {
                weights[p * pixels + i] = rng.uniform(-1.0, 1.0);
            }
        }
    }
    let w32: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    let run = gpu_run(rast, host, cam, bg, degree, Some(&w32));
    let grads = run.grads.unwrap();
    let gpu: Vec<(&str, f32)> = {
        let mut v = Vec::new();
        v.extend(grads.means.iter().map(|&x| ("means", x)));
        v.extend(grads.log_scales.iter().map(|&x| ("log_scales", x)));
        v.extend(grads.quats.iter().map(|&x| ("quats", x)));
        v.extend(grads.opacity.iter().map(|&x| ("opacity", x)));
        v.extend(grads.features.iter().map(|&x| ("features", x)));
        v
    };
    for (name, g) in &gpu {
        assert!(g.is_finite(), "{what}: non-finite GPU gradient in {name}");
    }
    let nparams = gpu.len();
    let mut fd = vec![0.0f64; nparams];
    let mut unstable = vec![false; nparams];
    let eps = 1e-6;
    for i in 0..nparams {
        let eval = |delta: f64| {
            let mut s = base.clone();
            let mut ps = s.params_mut();
            *ps[i].1 += delta;
            drop(ps);
            ref_loss(&s, cam, &bg64, degree, &weights)
        };
        let d1 = (eval(eps) - eval(-eps)) / (2.0 * eps);
        let d2 = (eval(eps / 2.0) - eval(-eps / 2.0)) / eps;
        fd[i] = d1;
        unstable[i] = (d1 - d2).abs() > 1e-4 * (1.0 + d1.abs());
    }
    let n_unstable = unstable.iter().filter(|&&u| u).count();
    eprintln!("{what}: {nparams} parameters, {n_unstable} on a discontinuity (left out)");
    assert!(n_unstable as f64 <= max_unstable * nparams as f64, "{what}: {n_unstable} of {nparams} finite differences unstable");
    for group in ["means", "log_scales", "quats", "opacity", "features"] {
        let (mut num, mut den, mut worst) = (0.0f64, 0.0f64, (0.0f64, 0usize));
        for i in 0..nparams {
            if gpu[i].0 != group || unstable[i] {
                continue;
            }
            let d = gpu[i].1 as f64 - fd[i];
            num += d * d;
            den += fd[i] * fd[i];
            if d.abs() > worst.0 {
                worst = (d.abs(), i);
            }
        }
        if den == 0.0 {
            assert!(num == 0.0, "{what}: {group}: finite differences are zero but the GPU gradient is not");
            assert!(zero_ok.contains(&group), "{what}: {group}: gradient is zero everywhere (nothing tested)");
            eprintln!("{what}: {group}: zero gradient (expected)");
            continue;
        }
        let rel = (num / den).sqrt();
        let wi = worst.1;
        eprintln!("{what}: {group}: relative error {rel:.2e} (|fd| = {:.3e}; worst param {wi}: gpu {} fd {})", den.sqrt(), gpu[wi].1, fd[wi]);
        assert!(rel <= 1e-2, "{what}: {group}: GPU gradient differs from finite differences: relative error {rel}");
    }
}

/// Upstream gradients for every output plane, all equal to `v`.
pub fn constant_grads(channels: u32, pixels: usize, v: f32) -> Vec<f32> {
    vec![v; Plane::count(channels) as usize * pixels]
}

/// Upstream gradients for every output plane, uniform in [-1, 1).
pub fn random_grads(rng: &mut Rng, channels: u32, pixels: usize) -> Vec<f32> {
    (0..Plane::count(channels) as usize * pixels).map(|_| rng.uniform(-1.0, 1.0) as f32).collect()
}

/// Degree-3 spherical harmonics, the rasterizer tests' usual features.
pub const SH3: Features = Features::Sh { degree: 3 };

/// Camera at the origin looking down +z (identity pose).
pub fn axis_camera(w: u32, h: u32, f: f32) -> Camera {
    Camera {
        width: w,
        height: h,
        fx: f,
        fy: f,
        cx: (w as f32 - 1.0) * 0.5,
        cy: (h as f32 - 1.0) * 0.5,
        world_to_view: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
    }
}

/// `n` features uniform in [-1, 1].
pub fn feats(rng: &mut Rng, n: usize) -> Vec<f32> {
    (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect()
}
