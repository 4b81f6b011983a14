//! Stage II's mechanism (the paper's §3.3: only the right normal fetches
//! the right radiance), end to end through `ReflectionModel::step`: a
//! reflection set lies on a mirror sphere under a smooth sky with its
//! normals tilted away from the surface, and trains on views whose colours
//! are what the true normals fetch. Its normals must turn back towards the
//! sphere. `Setup` holds the knobs behind the measurements in
//! perf/RESULTS.md (eighteenth session): the tilt, the splats' distance
//! from the sphere, the map (true and fixed, or grey and trained), the
//! rotation rate, normal consistency. On the same scene the last test
//! checks the penalty on R (`reflection.lambda_r`): in the loss, and
//! pulling R down.

use std::sync::Arc;
use tgs::train::stages::reflection::seed::quat_for_normal;
use tgs::train::stages::reflection::{ReflStepInput, ReflectionModel};
use tgs::train::TrainConfig;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::{Camera, EnvMap, Features, Fresnel, Gaussians, HostEnvMap, HostGaussians, Plane, Rasterizer, ReflectionShading};
use tgs_tests::raster_util::splat_normal;
use tgs_tests::{check_validation, ctx_shared, Rng};

type V3 = [f64; 3];

fn norm(v: V3) -> V3 {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| c / l)
}
fn cross(a: V3, b: V3) -> V3 {
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
}
fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn logit(p: f64) -> f32 {
    (p / (1.0 - p)).ln() as f32
}

/// A smooth but everywhere-varying sky: each channel a different low-order
/// function of the direction, in (0.1, 0.9).
fn sky(d: V3) -> [f64; 3] {
    [0.5 + 0.4 * d[1], 0.5 + 0.4 * (0.8 * d[0] + 0.6 * d[2]) * d[1].abs().max(0.3), 0.5 + 0.4 * (1.7 * d[2]).sin() * (1.3 * d[0]).cos()]
}

/// The cube map of `sky` at its texel centres.
fn sky_map(res: u32) -> HostEnvMap {
    let mut m = HostEnvMap::constant(res, 0.0).unwrap();
    for face in 0..6 {
        for y in 0..res {
            for x in 0..res {
                let d = HostEnvMap::texel_direction(res, face, y, x);
                let c = sky(norm(d.map(f64::from)));
                let t = ((face * res + y) * res + x) as usize;
                for ch in 0..3 {
                    m.raw[3 * t + ch] = logit(c[ch]);
                }
            }
        }
    }
    m
}

struct Scene {
    cams: Vec<Camera>,
    /// Points on the unit sphere: the splats' centres and true normals.
    points: Vec<V3>,
    scale: f32,
}

fn scene(views: usize, points: usize, side: u32) -> Scene {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let pts: Vec<V3> = (0..points)
        .map(|i| {
            let y = 1.0 - 2.0 * (i as f64 + 0.5) / points as f64;
            let r = (1.0 - y * y).sqrt();
            [r * (golden * i as f64).cos(), y, r * (golden * i as f64).sin()]
        })
        .collect();
    // Cameras on a ring at two heights, looking at the sphere.
    let cams = (0..views)
        .map(|i| {
            let a = 2.0 * std::f64::consts::PI * i as f64 / views as f64;
            let h = if i % 2 == 0 { 0.8 } else { -0.5 };
            let eye = [3.5 * a.cos(), h, 3.5 * a.sin()].map(|v| v as f32);
            Camera::look_at(eye, [0.0; 3], [0.0, 1.0, 0.0], 0.75, side, side)
        })
        .collect();
    // Splats wide enough to overlap their neighbours on the unit sphere.
    let scale = (2.2 * (4.0 * std::f64::consts::PI / points as f64).sqrt() / 2.0) as f32;
    Scene { cams, points: pts, scale }
}

/// Turn `n` by `angle` about a random axis perpendicular to it.
fn tilt(rng: &mut Rng, n: V3, angle: f64) -> V3 {
    let r = norm([0; 3].map(|_| rng.uniform(-1.0, 1.0)));
    // A unit vector perpendicular to n, and n turned towards it.
    let t = norm(cross(cross(n, r), n));
    norm(std::array::from_fn(|k| n[k] * angle.cos() + t[k] * angle.sin()))
}

fn set_with(s: &Scene, normals: &[V3], radius: f64) -> HostGaussians {
    let mut h = HostGaussians::new(4, 1);
    let ls = s.scale.ln();
    for (p, n) in s.points.iter().zip(normals) {
        h.push(p.map(|v| (v * radius) as f32), [ls, ls], quat_for_normal(n.map(|v| v as f32)), logit(0.95), &[logit(0.9), logit(0.9), logit(0.9), logit(0.6)]);
    }
    h
}

/// Mean angle (degrees) between the set's normals and the true ones, sign
/// ignored (the kernels turn every normal to face the camera).
fn mae(h: &HostGaussians, s: &Scene) -> f64 {
    let e: f64 = s.points.iter().enumerate().map(|(i, n)| dot(splat_normal(std::array::from_fn(|k| h.quats[4 * i + k])), *n).abs().min(1.0).acos().to_degrees()).sum();
    e / s.points.len() as f64
}

struct Outcome {
    before: f64,
    after: f64,
}

/// The training views of `cams`: the splats of `geometry` rasterized with
/// the colours the splats of `truth` (true normals) fetch from `env`,
/// composited over `scat`.
fn targets(ctx: &Arc<Context>, truth: &HostGaussians, geometry: &HostGaussians, env: &HostEnvMap, cams: &[Camera], scat: &Buffer<f32>) -> Vec<Buffer<f32>> {
    let fresnel = Fresnel::Off;
    let ch = fresnel.channels();
    let shading = ReflectionShading::new(ctx).unwrap();
    let raster = Rasterizer::new(ctx, ch, Features::Plain).unwrap();
    let (truth, geometry) = (Gaussians::upload(ctx, truth).unwrap(), Gaussians::upload(ctx, geometry).unwrap());
    let env = EnvMap::upload(ctx, env).unwrap();
    let n = geometry.n;
    let feat = Buffer::<f32>::new(ctx, "test.features", ch as usize * n as usize).unwrap();
    let background = vec![0.0; ch as usize];
    let mut out = Vec::new();
    for cam in cams {
        let mut frame = raster.frame(cam.width, cam.height, n, raster.initial_capacity(n)).unwrap();
        let img = Buffer::<f32>::new(ctx, "test.target", (Plane::count(3) * cam.width * cam.height) as usize).unwrap();
        loop {
            let mut rec = Recorder::new(ctx).unwrap();
            shading.record_color(&mut rec, &tgs_pipelines::ColorInputs { g: &truth, env: &env, cam, fresnel }, &feat).unwrap();
            raster.record_forward_with(&mut rec, tgs_pipelines::Splats::coloured(&geometry, &feat), cam, &background, &frame).unwrap();
            shading.record_composite(&mut rec, cam, fresnel, &tgs_pipelines::reflection::CompositeInputs { scat, refl: &frame.out }, &img).unwrap();
            rec.submit_and_wait().unwrap();
            if raster.fit(&mut frame).unwrap() {
                break;
            }
        }
        out.push(img);
    }
    out
}

/// One experiment: the splats' normals tilted by `tilt_deg`, their centres
/// at `radius` times the sphere's, trained `iterations` Stage II steps.
#[derive(Clone, Copy)]
struct Setup {
    tilt_deg: f64,
    radius: f64,
    iterations: u32,
    /// The true map, held fixed (with f0 and r); else a grey map of face
    /// size `env_res`, trained.
    env_known: bool,
    env_res: u32,
    lr_quats: f32,
    lambda_normal: f32,
    /// The training views show the splats where they start (tilted) in
    /// the colours the true normals fetch; else the true splats.
    colours_only: bool,
}

impl Default for Setup {
    fn default() -> Self {
        Setup { tilt_deg: 20.0, radius: 1.0, iterations: 1000, env_known: false, env_res: ENV_RES, lr_quats: 1e-2, lambda_normal: 0.0, colours_only: false }
    }
}

const ENV_RES: u32 = 16;

fn run(ctx: &Arc<Context>, x: &Setup) -> Outcome {
    let Setup { tilt_deg, radius, iterations, env_known, env_res, lr_quats, lambda_normal, colours_only } = *x;
    let s = scene(16, 600, 40);
    let env = sky_map(ENV_RES);
    let truth = s.points.clone();
    let n_px = (s.cams[0].width * s.cams[0].height) as usize;
    // The scattering layer behind: a flat mid grey.
    let scat = Buffer::<f32>::new(ctx, "test.scat", 3 * n_px).unwrap();
    scat.upload(&vec![0.5; 3 * n_px]).unwrap();
    let mut rng = Rng(0x5eed_0002);
    let tilted: Vec<V3> = truth.iter().map(|n| tilt(&mut rng, *n, tilt_deg.to_radians())).collect();
    let start = set_with(&s, &tilted, radius);
    let before = mae(&start, &s);
    let true_set = set_with(&s, &truth, 1.0);
    let geometry = if colours_only { &start } else { &true_set };
    let targets = targets(ctx, &true_set, geometry, &env, &s.cams, &scat);
    let grey = HostEnvMap::constant(env_res, 0.0).unwrap();
    let mut model = ReflectionModel::new(ctx, &start, if env_known { &env } else { &grey }, Fresnel::Off, 1e-15).unwrap();
    let mut cfg = TrainConfig::quick();
    let rc = &mut cfg.reflection;
    rc.lr_quats = lr_quats;
    rc.lambda_normal = lambda_normal;
    rc.lambda_hf = 0.0;
    rc.prune_interval = 0;
    rc.lr_opacity = 0.0;
    if env_known {
        rc.lr_env = 0.0;
        rc.lr_f0 = 0.0;
        rc.lr_r = 0.0;
    }
    for it in 1..=iterations {
        let v = (it as usize * 7) % s.cams.len();
        let x = ReflStepInput { iteration: it, camera: &s.cams[v], target: &targets[v], scat: Some(&scat), lr_means: 0.0, profile: false, mask: None };
        model.step(&cfg, &x, None).unwrap();
    }
    let after = mae(&model.set.params.download().unwrap(), &s);
    check_validation(ctx);
    Outcome { before, after }
}

/// The mechanism alone: the training views show the tilted splats' own
/// footprints in the colours the true normals fetch, so only the colour's
/// gradient through the mirror direction can turn the normals back, against
/// the footprints' pull to stay. With the true map held fixed 20 degrees
/// come down to 13.4 (measured at sub-group 8); with the colour's gradient
/// to the quaternions cut they end at 21.8.
#[test]
fn the_mirror_direction_turns_normals_towards_the_surface() {
    let o = run(ctx_shared(), &Setup { env_known: true, colours_only: true, ..Setup::default() });
    println!("colours only, true map: normal error {:.2} -> {:.2} degrees", o.before, o.after);
    assert!((o.before - 20.0).abs() < 0.01, "the start is tilted by {:.3} degrees, not 20", o.before);
    assert!(o.after.is_finite() && o.after < 17.0, "Stage II left the normals {:.2} degrees off the sphere (from {:.2})", o.after, o.before);
}

/// The whole of Stage II's training on splats that lie on the surface: the
/// training views are the true splats (the footprints pull too), the map
/// starts grey and trains with the normals, f0 and r. 20 degrees come back
/// to 3.0 (4.4 with normal consistency 0.05) at lr_quats 1e-2; at the
/// default 1e-4 they stay at 18.2, and from 45 degrees, or with the splats
/// 15% off the sphere, they do not come back (perf/RESULTS.md, eighteenth
/// session).
#[test]
fn stage_two_turns_tilted_normals_back_to_a_mirror_sphere() {
    for lambda_normal in [0.0, 0.05] {
        let o = run(ctx_shared(), &Setup { lambda_normal, ..Setup::default() });
        println!("grey map, normal consistency {lambda_normal}: normal error {:.2} -> {:.2} degrees", o.before, o.after);
        assert!(
            o.after.is_finite() && o.after < 8.0,
            "with normal consistency {lambda_normal} Stage II left the normals {:.2} degrees off the sphere (from {:.2})",
            o.after,
            o.before
        );
    }
}

/// `reflection.lambda_r`: a penalty lambda * mean(R) joins the step's loss
/// (the first step's loss rises by lambda times the mean of the R plane its
/// forward renders) and its gradient pulls R down: on the true sphere under
/// a grey map, after 300 steps at lambda_r 2, the views' mean R is 0.23
/// against 0.37 without the penalty (sub-group 8).
#[test]
fn a_penalty_on_r_joins_the_loss_and_lowers_r() {
    let ctx = ctx_shared();
    let s = scene(16, 600, 40);
    let n_px = (s.cams[0].width * s.cams[0].height) as usize;
    let scat = Buffer::<f32>::new(ctx, "test.scat", 3 * n_px).unwrap();
    scat.upload(&vec![0.5; 3 * n_px]).unwrap();
    let truth = set_with(&s, &s.points, 1.0);
    let targets = targets(ctx, &truth, &truth, &sky_map(ENV_RES), &s.cams, &scat);
    let grey = HostEnvMap::constant(ENV_RES, 0.0).unwrap();
    let lambda = 2.0f32;
    let view_of = |it: u32| (it as usize * 7) % s.cams.len();
    // Per run: the first step's loss, the mean R of its view before it, the
    // mean R over all views after training.
    let mut runs = Vec::new();
    for lambda_r in [0.0, lambda] {
        let mut model = ReflectionModel::new(ctx, &truth, &grey, Fresnel::Off, 1e-15).unwrap();
        let mut cfg = TrainConfig::quick();
        cfg.reflection.lambda_r = lambda_r;
        cfg.reflection.lambda_hf = 0.0;
        cfg.reflection.prune_interval = 0;
        let mean_r = |model: &mut ReflectionModel, v: usize| {
            let r = model.render(&s.cams[v], &scat).unwrap();
            r.r().iter().map(|&x| x as f64).sum::<f64>() / n_px as f64
        };
        let r_first = mean_r(&mut model, view_of(1));
        let mut first_loss = f64::NAN;
        for it in 1..=300u32 {
            let v = view_of(it);
            let x = ReflStepInput { iteration: it, camera: &s.cams[v], target: &targets[v], scat: Some(&scat), lr_means: 0.0, profile: false, mask: None };
            let out = model.step(&cfg, &x, None).unwrap();
            assert!(out.loss.is_finite(), "lambda_r {lambda_r}: loss {} at step {it}", out.loss);
            if it == 1 {
                first_loss = out.loss;
            }
        }
        let r_after = (0..s.cams.len()).map(|v| mean_r(&mut model, v)).sum::<f64>() / s.cams.len() as f64;
        runs.push((first_loss, r_first, r_after));
    }
    let [(l0, r_first, r0), (l1, _, r1)] = runs[..] else { unreachable!() };
    println!("first step's loss {l0:.6} without the penalty, {l1:.6} with lambda_r {lambda} (mean R {r_first:.5}); mean R after 300 steps {r0:.5} without, {r1:.5} with");
    let want = lambda as f64 * r_first;
    assert!(((l1 - l0) - want).abs() < 1e-5 * (1.0 + want), "the first step's loss rose by {} with the penalty, not lambda * mean R = {want}", l1 - l0);
    assert!(r1 < 0.75 * r0, "the penalty left the mean R at {r1:.5} (without it {r0:.5})");
    check_validation(ctx);
}
