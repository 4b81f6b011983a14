//! Stage II's kernels against the f64 reference (tests/src/reflection_ref.rs):
//! the cube-map lookup through the per-Gaussian colour (directions on axes,
//! seams, corners and random), the colour's backward (material, position,
//! quaternion through the mirror direction, texels through the sort-based
//! reduction) against central differences, the deferred composite with and
//! without Schlick (no coverage, grazing and head-on views), no NaN/Inf,
//! and bit-identical reruns.
//!
//! Longer than 500 lines on purpose: one test binary per kernel family (each
//! binary is linked separately, and links are a large part of CI's build),
//! and these cases share the reference's helpers.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Camera, ColorInputs, CompositePriors, EnvMap, EnvProxy, Fresnel, Gaussians, HostEnvMap, HostGaussians, Plane, ReflectionShading};
use tgs_tests::reflection_ref::{self as rr, CompositePixel, ReflGaussian, V3};
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

fn uni(rng: &mut Rng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
}

fn norm(v: V3) -> V3 {
    let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    v.map(|c| c / l)
}

/// Quaternion (r, x, y, z) turning +z into `n`.
fn quat_to(n: V3) -> [f64; 4] {
    if n[2] < -0.999999 {
        return [0.0, 1.0, 0.0, 0.0];
    }
    let q = [1.0 + n[2], -n[1], n[0], 0.0];
    let l = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / l)
}

const CENTRE: V3 = [0.3, -0.2, 4.0];

fn camera() -> Camera {
    Camera::look_at([CENTRE[0] as f32, CENTRE[1] as f32, CENTRE[2] as f32], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0], 0.8, 16, 16)
}

/// A Gaussian at `p` whose mirror direction seen from CENTRE is `w`.
fn gaussian_reflecting(p: V3, w: V3, material: [f64; 4]) -> ReflGaussian {
    let v = norm([CENTRE[0] - p[0], CENTRE[1] - p[1], CENTRE[2] - p[2]]);
    let n = norm([v[0] + w[0], v[1] + w[1], v[2] + w[2]]);
    ReflGaussian { p, q: quat_to(n), material }
}

/// `n` random Gaussians, each facing a random direction.
fn random_gaussians(rng: &mut Rng, n: usize) -> Vec<ReflGaussian> {
    (0..n)
        .map(|_| {
            let w = random_dir(rng);
            random_gaussian(rng, w)
        })
        .collect()
}

fn random_gaussian(rng: &mut Rng, w: V3) -> ReflGaussian {
    let p = [uni(rng, -1.0, 1.0), uni(rng, -1.0, 1.0), uni(rng, -1.0, 1.0)];
    let material = [uni(rng, -3.0, 3.0), uni(rng, -3.0, 3.0), uni(rng, -3.0, 3.0), uni(rng, -3.0, 3.0)];
    let mut g = gaussian_reflecting(p, w, material);
    // Unnormalized quaternions: the kernels normalize.
    let s = uni(rng, 0.5, 2.0);
    g.q = g.q.map(|v| v * s);
    g
}

/// The Gaussian as the GPU sees it (every value rounded to f32).
fn round32(g: &ReflGaussian) -> ReflGaussian {
    let r = |v: f64| v as f32 as f64;
    ReflGaussian { p: g.p.map(r), q: g.q.map(r), material: g.material.map(r) }
}

fn random_dir(rng: &mut Rng) -> V3 {
    loop {
        let d = [uni(rng, -1.0, 1.0), uni(rng, -1.0, 1.0), uni(rng, -1.0, 1.0)];
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        if l > 0.1 && l < 1.0 {
            return d.map(|c| c / l);
        }
    }
}

/// Axes, seam midpoints, corners, and points just off seams.
fn special_dirs() -> Vec<V3> {
    let mut out = Vec::new();
    for a in 0..3 {
        for s in [1.0, -1.0] {
            let mut d = [0.0; 3];
            d[a] = s;
            out.push(d);
        }
    }
    for (a, b) in [(0, 1), (0, 2), (1, 2)] {
        for (sa, sb) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
            let mut d = [0.0; 3];
            d[a] = sa;
            d[b] = sb;
            out.push(norm(d));
            d[a] *= 1.001;
            out.push(norm(d));
            d[a] /= 1.001 * 1.001;
            d[(3 - a - b) % 3] = 0.3;
            out.push(norm(d));
        }
    }
    for x in [1.0, -1.0] {
        for y in [1.0, -1.0] {
            for z in [1.0, -1.0] {
                out.push(norm([x, y, z]));
            }
        }
    }
    out
}

fn host_set(gs: &[ReflGaussian]) -> HostGaussians {
    let mut h = HostGaussians::new(4, 1);
    for g in gs {
        let m = g.material.map(|v| v as f32);
        h.push(g.p.map(|v| v as f32), [-3.0, -3.0], g.q.map(|v| v as f32), 2.0, &m);
    }
    h
}

fn random_env(rng: &mut Rng, res: usize) -> Vec<f64> {
    (0..6 * res * res * 3).map(|_| uni(rng, -2.0, 2.0)).collect()
}

/// A parallax proxy (centre, radius) as the GPU takes it.
fn gpu_proxy(proxy: Option<(V3, f64)>) -> Option<EnvProxy> {
    proxy.map(|(c, r)| EnvProxy { centre: c.map(|v| v as f32), radius: r as f32 })
}

/// The proxy as the GPU sees it (rounded to f32).
fn proxy32(proxy: Option<(V3, f64)>) -> Option<(V3, f64)> {
    proxy.map(|(c, r)| (c.map(|v| v as f32 as f64), r as f32 as f64))
}

/// With a depth map (distances from the proxy's centre per texel).
fn upload_env_light(ctx: &std::sync::Arc<tgs_engine::Context>, res: usize, raw: &[f64], proxy: Option<(V3, f64)>, depth: Option<&[f64]>) -> EnvMap {
    let depth = depth.map(|d| d.iter().map(|&v| v as f32).collect());
    EnvMap::upload(ctx, &HostEnvMap { res: res as u32, raw: raw.iter().map(|&v| v as f32).collect(), proxy: gpu_proxy(proxy), depth }).unwrap()
}

fn gpu_color(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel) -> Vec<f32> {
    gpu_color_proxy(gs, env, res, fresnel, None)
}

fn gpu_color_proxy(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel, proxy: Option<(V3, f64)>) -> Vec<f32> {
    gpu_color_light(gs, env, res, fresnel, proxy, None)
}

fn gpu_color_light(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel, proxy: Option<(V3, f64)>, depth: Option<&[f64]>) -> Vec<f32> {
    let ctx = ctx_shared();
    let shading = ReflectionShading::new(ctx).unwrap();
    let g = Gaussians::upload(ctx, &host_set(gs)).unwrap();
    let e = upload_env_light(ctx, res, env, proxy, depth);
    let feat = Buffer::<f32>::new(ctx, "test.feat", fresnel.channels() as usize * gs.len()).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    shading.record_color(&mut rec, &ColorInputs { g: &g, env: &e, cam: &camera(), fresnel }, &feat).unwrap();
    rec.submit_and_wait().unwrap();
    feat.download().unwrap()
}

#[test]
fn color_matches_reference_on_axes_seams_corners_and_random_directions() {
    let mut rng = Rng(seed("color_forward"));
    for res in [1usize, 3, 4, 16] {
        let env = random_env(&mut rng, res);
        let mut dirs = special_dirs();
        dirs.extend((0..200).map(|_| random_dir(&mut rng)));
        let gs: Vec<_> = dirs.iter().map(|&w| random_gaussian(&mut rng, w)).collect();
        for fresnel in [Fresnel::Off, Fresnel::Schlick] {
            let ch = fresnel.channels() as usize;
            let got = gpu_color(&gs, &env, res, fresnel);
            for (i, g) in gs.iter().enumerate() {
                // The reference from the direction the f32 kernel sees (the
                // quaternion rounded to f32) to keep ties on seams the same.
                let g32 = round32(g);
                let centre = CENTRE.map(|v| v as f32 as f64);
                let want = rr::color(&g32, &env, res, centre, fresnel == Fresnel::Schlick);
                let got_i = &got[ch * i..ch * (i + 1)];
                assert!(got_i.iter().all(|v| v.is_finite()), "res {res} {fresnel:?} Gaussian {i}: non-finite {got_i:?}");
                let matches = |want: &[f64]| (0..ch).all(|c| (got_i[c] as f64 - want[c]).abs() < 2e-4);
                if matches(&want) {
                    continue;
                }
                // Exactly on a seam or corner the face is a tie that f32 and
                // f64 may break differently: accept the lookup of any face
                // meeting there (the direction moved by 1e-6).
                let w = rr::mirror_dir(&g32, centre);
                let tie_ok = (0..6).any(|k| {
                    let mut d = w;
                    d[k / 2] += if k % 2 == 0 { 1e-6 } else { -1e-6 };
                    let e = rr::env_lookup(&env, res, norm(d));
                    let f0 = [0, 1, 2].map(|c| 1.0 / (1.0 + (-g32.material[c]).exp()));
                    let c3: Vec<f64> = if fresnel == Fresnel::Schlick { e.to_vec() } else { (0..3).map(|c| f0[c] * e[c]).collect() };
                    (0..3).all(|c| (got_i[c] as f64 - c3[c]).abs() < 2e-4)
                });
                assert!(tie_ok, "res {res} {fresnel:?} Gaussian {i} (w = {:?}): GPU {got_i:?} vs f64 {want:?}", dirs[i]);
            }
        }
    }
    check_validation(ctx_shared());
}

#[test]
fn lookup_is_continuous_across_seams() {
    // A smooth environment (texel value = a function of its direction): the
    // lookup on both sides of a seam, 1e-4 apart, differs by at most what
    // one texel step of that function allows.
    let res = 8usize;
    let mut env = vec![0.0; 6 * res * res * 3];
    for face in 0..6 {
        for row in 0..res {
            for col in 0..res {
                let s = 2.0 / res as f64;
                let d = norm(rr::face_dir(face, (col as f64 + 0.5) * s - 1.0, (row as f64 + 0.5) * s - 1.0));
                let t = (face * res + row) * res + col;
                for c in 0..3 {
                    env[3 * t + c] = 2.0 * d[c];
                }
            }
        }
    }
    let mut rng = Rng(seed("seams"));
    for _ in 0..200 {
        // A point on a random seam: two major components equal.
        let mut d = random_dir(&mut rng);
        let (a, b) = [(0, 1), (0, 2), (1, 2)][rng.below(3) as usize];
        let m = d[a].abs().max(d[b].abs()).max(d[3 - a - b].abs() + 0.05);
        d[a] = m * d[a].signum();
        d[b] = m * d[b].signum();
        let mut d1 = d;
        d1[a] *= 1.0 + 1e-4;
        let mut d2 = d;
        d2[b] *= 1.0 + 1e-4;
        let (e1, e2) = (rr::env_lookup(&env, res, norm(d1)), rr::env_lookup(&env, res, norm(d2)));
        for c in 0..3 {
            assert!((e1[c] - e2[c]).abs() < 0.05, "seam at {d:?}: {e1:?} vs {e2:?}");
        }
    }
}

struct Backward {
    material: Vec<f32>,
    means: Vec<f32>,
    quats: Vec<f32>,
    env: Vec<f32>,
}

fn gpu_backward(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel, dfeat: &[f64], proxy: Option<(V3, f64)>) -> Backward {
    gpu_backward_light(gs, env, res, fresnel, dfeat, proxy, None)
}

fn gpu_backward_light(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel, dfeat: &[f64], proxy: Option<(V3, f64)>, depth: Option<&[f64]>) -> Backward {
    let ctx = ctx_shared();
    let shading = ReflectionShading::new(ctx).unwrap();
    let g = Gaussians::upload(ctx, &host_set(gs)).unwrap();
    let grads = Gaussians::zeros(ctx, gs.len() as u32, 4, 1).unwrap();
    let e = upload_env_light(ctx, res, env, proxy, depth);
    let df: Vec<f32> = dfeat.iter().map(|&v| v as f32).collect();
    let d = Buffer::from_slice(ctx, "test.dfeat", &df).unwrap();
    let s = shading.texel_scratch(&e, gs.len() as u32).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    shading.record_color_backward(&mut rec, &ColorInputs { g: &g, env: &e, cam: &camera(), fresnel }, &d, &grads, &s).unwrap();
    rec.submit_and_wait().unwrap();
    let h = grads.download().unwrap();
    Backward { material: h.features, means: h.means, quats: h.quats, env: e.grads.download().unwrap() }
}

fn ref_loss(gs: &[ReflGaussian], env: &[f64], res: usize, schlick: bool, dfeat: &[f64], proxy: Option<(V3, f64)>) -> f64 {
    let ch = if schlick { 7 } else { 4 };
    gs.iter().enumerate().map(|(i, g)| rr::color_with_proxy(g, env, res, CENTRE, proxy, schlick).iter().enumerate().map(|(c, v)| v * dfeat[ch * i + c]).sum::<f64>()).sum()
}

fn close(got: f32, want: f64, scale: f64) -> bool {
    got.is_finite() && (got as f64 - want).abs() <= 2e-3 * scale + 1e-3 * want.abs()
}

fn check_backward(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel, rng: &mut Rng, what: &str, proxy: Option<(V3, f64)>) -> Backward {
    let proxy = proxy32(proxy);
    let schlick = fresnel == Fresnel::Schlick;
    let what = format!("{what} (proxy {proxy:?})");
    let gpu = |gs: &[ReflGaussian], env: &[f64], dfeat: &[f64]| gpu_backward(gs, env, res, fresnel, dfeat, proxy);
    let loss = |gs: &[ReflGaussian], env: &[f64], dfeat: &[f64]| ref_loss(gs, env, res, schlick, dfeat, proxy);
    check_backward_with(gs, env, res, fresnel, rng, &what, &gpu, &loss)
}

/// A function of the set, the texels and the feature gradients.
type SetFn<'a, T> = dyn Fn(&[ReflGaussian], &[f64], &[f64]) -> T + 'a;

/// The colour backward `gpu` (Gaussians, texels, feature gradients) against
/// central differences of the reference `loss` (the same arguments; the
/// inputs rounded to f32 as the GPU sees them).
#[allow(clippy::too_many_arguments)]
fn check_backward_with(gs: &[ReflGaussian], env: &[f64], res: usize, fresnel: Fresnel, rng: &mut Rng, what: &str, gpu: &SetFn<'_, Backward>, loss: &SetFn<'_, f64>) -> Backward {
    let ch = fresnel.channels() as usize;
    let dfeat: Vec<f64> = (0..ch * gs.len()).map(|_| uni(rng, -1.0, 1.0)).collect();
    // The reference sees the f32-rounded inputs the GPU sees.
    let gs: Vec<ReflGaussian> = gs.iter().map(round32).collect();
    let env: Vec<f64> = env.iter().map(|&v| v as f32 as f64).collect();
    let dfeat: Vec<f64> = dfeat.iter().map(|&v| v as f32 as f64).collect();
    let got = gpu(&gs, &env, &dfeat);
    let h = 1e-6;
    let fd = |f: &dyn Fn(f64) -> f64| (f(h) - f(-h)) / (2.0 * h);
    let mut bad = Vec::new();
    for i in 0..gs.len() {
        let with = |k: &dyn Fn(&mut ReflGaussian, f64), e: f64| {
            let mut m = gs.clone();
            k(&mut m[i], e);
            loss(&m, &env, &dfeat)
        };
        for c in 0..4 {
            let want = fd(&|e| with(&|g, e| g.material[c] += e, e));
            if !close(got.material[4 * i + c], want, 1.0) {
                bad.push(format!("Gaussian {i} material[{c}]: GPU {} vs FD {want}", got.material[4 * i + c]));
            }
        }
        // A mirror direction within rounding of a texel boundary (a tap
        // weight below 1e-4) puts the f32 lookup and the f64 difference on
        // either side of the bilinear kink: its geometry is not compared
        // (seen once in CI: tap weights 4.2e-6 and 1.2e-6).
        if rr::taps(rr::mirror_dir(&gs[i], CENTRE), res).iter().any(|&(_, wt)| wt > 0.0 && wt < 1e-4) {
            continue;
        }
        let scale = (0..3).map(|c| fd(&|e| with(&|g, e| g.p[c] += e, e)).abs()).fold(1.0, f64::max);
        for c in 0..3 {
            let want = fd(&|e| with(&|g, e| g.p[c] += e, e));
            if !close(got.means[3 * i + c], want, scale) {
                bad.push(format!("Gaussian {i} mean[{c}]: GPU {} vs FD {want}", got.means[3 * i + c]));
            }
        }
        let scale = (0..4).map(|c| fd(&|e| with(&|g, e| g.q[c] += e, e)).abs()).fold(1.0, f64::max);
        for c in 0..4 {
            let want = fd(&|e| with(&|g, e| g.q[c] += e, e));
            if !close(got.quats[4 * i + c], want, scale) {
                bad.push(format!("Gaussian {i} quat[{c}]: GPU {} vs FD {want}", got.quats[4 * i + c]));
            }
        }
    }
    let scale = 1.0f64.max(got.env.iter().fold(0.0f64, |a, &b| a.max(b.abs() as f64)));
    for t in 0..env.len() {
        let want = fd(&|e| {
            let mut m = env.clone();
            m[t] += e;
            loss(&gs, &m, &dfeat)
        });
        if !close(got.env[t], want, scale) {
            bad.push(format!("texel value {t}: GPU {} vs FD {want}", got.env[t]));
        }
    }
    if !bad.is_empty() {
        for (i, g) in gs.iter().enumerate() {
            let w = rr::mirror_dir(g, CENTRE);
            eprintln!("Gaussian {i}: w {w:?} face {:?} taps {:?}", rr::cube_coords(w), rr::taps(w, res));
        }
    }
    assert!(bad.is_empty(), "{what} ({fresnel:?}, res {res}): {} mismatches:\n{}", bad.len(), bad[..bad.len().min(20)].join("\n"));
    got
}

/// A proxy around the Gaussians (|p| <= sqrt 3) that also leaves some
/// outside it, where the lookup falls back to the mirror direction.
const PROXY: (V3, f64) = ([0.2, -0.3, 0.1], 1.2);

#[test]
fn parallax_proxy_lookup_matches_reference() {
    // The reference's exit point lies on the sphere, beyond p, along w.
    let mut rng = Rng(seed("proxy_dir"));
    for _ in 0..200 {
        let p = [uni(&mut rng, -1.0, 1.0), uni(&mut rng, -1.0, 1.0), uni(&mut rng, -1.0, 1.0)];
        let w = random_dir(&mut rng);
        let (c, r) = PROXY;
        let d = rr::proxy_dir(p, w, Some(PROXY));
        let o = [p[0] - c[0], p[1] - c[1], p[2] - c[2]];
        if (o[0] * o[0] + o[1] * o[1] + o[2] * o[2]).sqrt() >= r {
            assert_eq!(d, w, "outside the sphere: the mirror direction");
            continue;
        }
        let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        assert!((len - r).abs() < 1e-9, "exit point at distance {len} from the centre, not {r}");
        let t: f64 = (0..3).map(|k| (d[k] - o[k]) * w[k]).sum();
        assert!(t > 0.0 && (0..3).all(|k| (o[k] + t * w[k] - d[k]).abs() < 1e-9), "not ahead along w");
        // A huge sphere is the map at infinity: the direction tends to w.
        let far = norm(rr::proxy_dir(p, w, Some((c, 1e7))));
        assert!((0..3).all(|k| (far[k] - w[k]).abs() < 1e-6));
    }
    // The GPU colour through the proxy, against the reference.
    for res in [3usize, 16] {
        let env = random_env(&mut rng, res);
        let mut dirs = special_dirs();
        dirs.extend((0..200).map(|_| random_dir(&mut rng)));
        let mut gs: Vec<_> = dirs.iter().map(|&w| random_gaussian(&mut rng, w)).collect();
        // At the proxy's centre and on its boundary's inside.
        gs[0].p = PROXY.0;
        gs[1].p = [PROXY.0[0] + 1.199, PROXY.0[1], PROXY.0[2]];
        for fresnel in [Fresnel::Off, Fresnel::Schlick] {
            let ch = fresnel.channels() as usize;
            let got = gpu_color_proxy(&gs, &env, res, fresnel, Some(PROXY));
            let (mut inside, mut off) = (0, 0);
            for (i, g) in gs.iter().enumerate() {
                let g32 = round32(g);
                let centre = CENTRE.map(|v| v as f32 as f64);
                let want = rr::color_with_proxy(&g32, &env, res, centre, proxy32(Some(PROXY)), fresnel == Fresnel::Schlick);
                let got_i = &got[ch * i..ch * (i + 1)];
                assert!(got_i.iter().all(|v| v.is_finite()), "res {res} {fresnel:?} Gaussian {i}: {got_i:?}");
                if (0..ch).all(|c| (got_i[c] as f64 - want[c]).abs() < 2e-4) {
                    let o: f64 = (0..3).map(|k| (g32.p[k] - PROXY.0[k]).powi(2)).sum::<f64>().sqrt();
                    if o < PROXY.1 {
                        inside += 1
                    } else {
                        off += 1
                    }
                    continue;
                }
                // A tie on a seam (as in the test without a proxy).
                let d = rr::proxy_dir(g32.p, rr::mirror_dir(&g32, centre), proxy32(Some(PROXY)));
                let tie_ok = (0..6).any(|k| {
                    let mut d2 = norm(d);
                    d2[k / 2] += if k % 2 == 0 { 1e-6 } else { -1e-6 };
                    let e = rr::env_lookup(&env, res, norm(d2));
                    let f0 = [0, 1, 2].map(|c| 1.0 / (1.0 + (-g32.material[c]).exp()));
                    (0..3).all(|c| (got_i[c] as f64 - if fresnel == Fresnel::Schlick { e[c] } else { f0[c] * e[c] }).abs() < 2e-4)
                });
                assert!(tie_ok, "res {res} {fresnel:?} Gaussian {i}: GPU {got_i:?} vs f64 {want:?}");
            }
            assert!(inside > 50 && off > 10, "the cases cover both sides of the sphere: {inside} inside, {off} outside");
        }
    }
    check_validation(ctx_shared());
}

/// A smooth depth map (distances 0.8 to 2.0 from the centre), rounded to
/// f32 as the GPU holds it: around the test Gaussians (|p - c| up to
/// about 2.1), so a lookup holds p in some directions and not in others.
fn smooth_depth(res: usize) -> Vec<f64> {
    let mut out = vec![0.0; 6 * res * res];
    for face in 0..6 {
        for row in 0..res {
            for col in 0..res {
                let s = 2.0 / res as f64;
                let d = norm(rr::face_dir(face, (col as f64 + 0.5) * s - 1.0, (row as f64 + 0.5) * s - 1.0));
                out[(face * res + row) * res + col] = (1.4 + 0.6 * (2.0 * d[0]).sin() * (1.5 * d[1] + d[2]).cos()) as f32 as f64;
            }
        }
    }
    out
}

const DEPTH_ITERS: u32 = tgs_pipelines::reflection::DEPTH_ITERS;

#[test]
fn depth_mapped_lookup_matches_reference() {
    let mut rng = Rng(seed("depth_dir"));
    let c32 = proxy32(Some(PROXY)).unwrap().0;
    let centre = CENTRE.map(|v| v as f32 as f64);
    for res in [3usize, 16] {
        let env = random_env(&mut rng, res);
        let depth = smooth_depth(res);
        let mut dirs = special_dirs();
        dirs.extend((0..200).map(|_| random_dir(&mut rng)));
        let mut gs: Vec<_> = dirs.iter().map(|&w| random_gaussian(&mut rng, w)).collect();
        // At the centre the lookup is w's own direction at every step.
        gs[0].p = PROXY.0;
        for fresnel in [Fresnel::Off, Fresnel::Schlick] {
            let schlick = fresnel == Fresnel::Schlick;
            let ch = fresnel.channels() as usize;
            let got = gpu_color_light(&gs, &env, res, fresnel, Some(PROXY), Some(&depth));
            let (mut moved, mut kept, mut near) = (0, 0, 0);
            for (i, g) in gs.iter().enumerate() {
                let g32 = round32(g);
                let w = rr::mirror_dir(&g32, centre);
                let (d, last, margin) = rr::depth_dir(g32.p, w, c32, &depth, res, DEPTH_ITERS);
                let want = rr::color_along(&g32, &env, res, d, schlick);
                let got_i = &got[ch * i..ch * (i + 1)];
                assert!(got_i.iter().all(|v| v.is_finite()), "res {res} {fresnel:?} Gaussian {i}: {got_i:?}");
                if (0..ch).all(|c| (got_i[c] as f64 - want[c]).abs() < 2e-4) {
                    if last.is_some() {
                        moved += 1
                    } else {
                        kept += 1
                    }
                    continue;
                }
                // f32 and f64 may take a different number of steps where a
                // step is within rounding of switching.
                if margin < 1e-4 {
                    near += 1;
                    continue;
                }
                // A tie on a seam or corner, of the final direction or of
                // the mirror direction the first depth lookup takes.
                let nudge = |v: V3, k: usize| {
                    let mut v = norm(v);
                    v[k / 2] += if k.is_multiple_of(2) { 1e-6 } else { -1e-6 };
                    v
                };
                let matches = |d2: V3| (0..3).all(|c| (got_i[c] as f64 - rr::color_along(&g32, &env, res, d2, schlick)[c]).abs() < 2e-4);
                let tie_ok = (0..6).any(|k| matches(nudge(d, k)) || matches(rr::depth_dir(g32.p, nudge(w, k), c32, &depth, res, DEPTH_ITERS).0));
                assert!(tie_ok, "res {res} {fresnel:?} Gaussian {i} (margin {margin}, w {w:?}): GPU {got_i:?} vs f64 {want:?}");
            }
            assert!(moved > 50 && kept > 10 && near < 5, "the cases cover both: {moved} looked up through the depth, {kept} kept w, {near} on a switch");
        }
        // No surface holds any point (depth 0): every ray leaves every
        // sphere at once and the lookup is w itself, bit for bit as without
        // a proxy. A constant depth is the one-sphere proxy of that radius.
        let fresnel = Fresnel::Schlick;
        let none = gpu_color_light(&gs, &env, res, fresnel, Some(PROXY), Some(&vec![0.0; 6 * res * res]));
        assert_eq!(none, gpu_color(&gs, &env, res, fresnel), "an empty depth map must look up the mirror direction");
        let one = gpu_color_light(&gs, &env, res, fresnel, Some(PROXY), Some(&vec![PROXY.1; 6 * res * res]));
        let sphere = gpu_color_proxy(&gs, &env, res, fresnel, Some(PROXY));
        for (i, (a, b)) in one.iter().zip(&sphere).enumerate() {
            assert!((a - b).abs() < 1e-5, "constant depth {}: value {i} is {a}, the sphere proxy gives {b}", PROXY.1);
        }
    }
    check_validation(ctx_shared());
}

#[test]
fn depth_mapped_backward_matches_finite_differences() {
    // The backward holds the last step's radius fixed: the finite
    // differences of the reference through a sphere of that radius per
    // Gaussian. Gaussians within 1e-3 of a step's switch are redrawn (there
    // the number of steps, and so the radius, can jump).
    let mut rng = Rng(seed("depth_backward"));
    let res = 3;
    let depth = smooth_depth(res);
    let c32 = proxy32(Some(PROXY)).unwrap().0;
    let centre = CENTRE.map(|v| v as f32 as f64);
    for fresnel in [Fresnel::Off, Fresnel::Schlick] {
        let schlick = fresnel == Fresnel::Schlick;
        let env = random_env(&mut rng, res);
        // Both kinds of lookup by construction (16 through the depth, 8
        // keeping w): a random draw alone can miss the rarer kind.
        let (mut moved, mut kept) = (Vec::new(), Vec::new());
        for _ in 0..100_000 {
            if moved.len() >= 16 && kept.len() >= 8 {
                break;
            }
            let w = random_dir(&mut rng);
            let g = round32(&random_gaussian(&mut rng, w));
            // The radius of the last step, kept for the reference below.
            let (_, last, margin) = rr::depth_dir(g.p, rr::mirror_dir(&g, centre), c32, &depth, res, DEPTH_ITERS);
            match last {
                _ if margin <= 1e-3 => {}
                Some(_) if moved.len() < 16 => moved.push((g, last)),
                None if kept.len() < 8 => kept.push((g, last)),
                _ => {}
            }
        }
        assert!(moved.len() == 16 && kept.len() == 8, "both kinds of lookup: {} through the depth, {} keeping w", moved.len(), kept.len());
        let (gs, radii): (Vec<ReflGaussian>, Vec<Option<f64>>) = moved.into_iter().chain(kept).unzip();
        let gpu = |gs: &[ReflGaussian], env: &[f64], dfeat: &[f64]| gpu_backward_light(gs, env, res, fresnel, dfeat, Some(PROXY), Some(&depth));
        let loss = |gs: &[ReflGaussian], env: &[f64], dfeat: &[f64]| {
            let ch = fresnel.channels() as usize;
            gs.iter()
                .enumerate()
                .map(|(i, g)| {
                    let d = rr::proxy_dir(g.p, rr::mirror_dir(g, CENTRE), radii[i].map(|r| (c32, r)));
                    rr::color_along(g, env, res, d, schlick).iter().enumerate().map(|(c, v)| v * dfeat[ch * i + c]).sum::<f64>()
                })
                .sum()
        };
        let a = check_backward_with(&gs, &env, res, fresnel, &mut rng, "depth-mapped lookup", &gpu, &loss);
        // Bit-identical on a rerun.
        let dfeat: Vec<f64> = (0..fresnel.channels() as usize * gs.len()).map(|_| uni(&mut rng, -1.0, 1.0) as f32 as f64).collect();
        let (x, y) = (gpu(&gs, &env, &dfeat), gpu(&gs, &env, &dfeat));
        let bits = |b: &Backward| [&b.material, &b.means, &b.quats, &b.env].iter().flat_map(|v| v.iter().map(|f| f.to_bits())).collect::<Vec<_>>();
        assert_eq!(bits(&x), bits(&y), "the depth-mapped backward differs between identical runs");
        assert!(bits(&a).iter().all(|&b| f32::from_bits(b).is_finite()));
    }
    check_validation(ctx_shared());
}

#[test]
fn color_backward_matches_finite_differences() {
    let mut rng = Rng(seed("color_backward"));
    // The map at infinity, and through a parallax proxy that holds some of
    // the Gaussians and not others.
    for proxy in [None, Some(PROXY)] {
        for fresnel in [Fresnel::Off, Fresnel::Schlick] {
            let env = random_env(&mut rng, 3);
            let gs = random_gaussians(&mut rng, 24);
            check_backward(&gs, &env, 3, fresnel, &mut rng, "random directions", proxy);
        }
    }
    check_validation(ctx_shared());
}

#[test]
fn texel_gradients_sum_many_gaussians_per_texel_deterministically() {
    // One texel per face: 300 Gaussians x 4 taps land on 6 texels, so every
    // texel's slots span several reduction chunks.
    let mut rng = Rng(seed("texel_sum"));
    let env = random_env(&mut rng, 1);
    let gs = random_gaussians(&mut rng, 300);
    let ch = Fresnel::Off.channels() as usize;
    let dfeat: Vec<f64> = (0..ch * gs.len()).map(|_| uni(&mut rng, -1.0, 1.0) as f32 as f64).collect();
    let a = gpu_backward(&gs, &env, 1, Fresnel::Off, &dfeat, None);
    let b = gpu_backward(&gs, &env, 1, Fresnel::Off, &dfeat, None);
    assert_eq!(a.env.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), b.env.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), "texel gradients differ between identical runs");
    assert_eq!(a.quats.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), b.quats.iter().map(|v| v.to_bits()).collect::<Vec<_>>());
    // Against central differences of the f64 reference.
    let gs32: Vec<ReflGaussian> = gs.iter().map(round32).collect();
    let env32: Vec<f64> = env.iter().map(|&v| v as f32 as f64).collect();
    for t in 0..env.len() {
        let h = 1e-6;
        let f = |e: f64| {
            let mut m = env32.clone();
            m[t] += e;
            ref_loss(&gs32, &m, 1, false, &dfeat, None)
        };
        let want = (f(h) - f(-h)) / (2.0 * h);
        assert!(close(a.env[t], want, 1.0 + want.abs()), "texel value {t}: GPU {} vs FD {want}", a.env[t]);
    }
    check_validation(ctx_shared());
}

#[test]
fn degenerate_reflection_gaussians_stay_finite() {
    // Zero and huge quaternions, a Gaussian at the camera centre, edge-on
    // normals (n . v = 0: w = -v), saturated material.
    let mut rng = Rng(seed("refl_degenerate"));
    let env = random_env(&mut rng, 4);
    let v = norm(CENTRE);
    let edge_n = norm([v[1], -v[0], 0.0]);
    let gs = vec![
        ReflGaussian { p: [0.0; 3], q: [0.0; 4], material: [0.0; 4] },
        ReflGaussian { p: [0.0; 3], q: [1e19, 0.0, 0.0, 0.0], material: [80.0, -80.0, 80.0, -80.0] },
        ReflGaussian { p: CENTRE, q: [1.0, 0.0, 0.0, 0.0], material: [0.0; 4] },
        ReflGaussian { p: [0.0; 3], q: quat_to(edge_n), material: [1.0; 4] },
        ReflGaussian { p: [1e-30, 0.0, 0.0], q: [1e-20, 0.0, 0.0, 0.0], material: [0.0; 4] },
    ];
    let mut gs = gs;
    // Exactly on a parallax proxy's sphere (radius 1 about the origin).
    gs.push(ReflGaussian { p: [1.0, 0.0, 0.0], q: quat_to(v), material: [0.0; 4] });
    // The proxy centred on Gaussians at the origin, and one too small to hold any.
    for proxy in [None, Some(([0.0; 3], 1.0)), Some(([0.0; 3], 1e-30))] {
        for fresnel in [Fresnel::Off, Fresnel::Schlick] {
            let feat = gpu_color_proxy(&gs, &env, 4, fresnel, proxy);
            assert!(feat.iter().all(|v| v.is_finite()), "{fresnel:?} {proxy:?}: non-finite colour {feat:?}");
            let dfeat = vec![1.0; fresnel.channels() as usize * gs.len()];
            let b = gpu_backward(&gs, &env, 4, fresnel, &dfeat, proxy);
            for (name, v) in [("material", &b.material), ("means", &b.means), ("quats", &b.quats), ("env", &b.env)] {
                assert!(v.iter().all(|x| x.is_finite()), "{fresnel:?} {proxy:?}: non-finite {name} gradient {v:?}");
            }
        }
    }
    check_validation(ctx_shared());
}

// ---- the deferred composite ----

fn comp_camera(w: u32, h: u32) -> Camera {
    Camera {
        width: w,
        height: h,
        fx: 1.1 * w as f32,
        fy: 1.05 * w as f32,
        cx: 0.45 * w as f32,
        cy: 0.55 * h as f32,
        world_to_view: [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0]],
    }
}

/// Random per-pixel inputs with the hard cases in the first pixels: no
/// reflection coverage, grazing (n . v = 0), head-on (n = v), zero normal.
fn composite_inputs(rng: &mut Rng, cam: &Camera) -> Vec<CompositePixel> {
    let n = (cam.width * cam.height) as usize;
    (0..n)
        .map(|i| {
            let (x, y) = ((i % cam.width as usize) as f64, (i / cam.width as usize) as f64);
            let v = rr::pixel_view_dir(x, y, cam.fx as f64, cam.fy as f64, cam.cx as f64, cam.cy as f64);
            let alpha = uni(rng, 0.2, 1.0);
            let mut nrm = norm([uni(rng, -0.5, 0.5) + v[0], uni(rng, -0.5, 0.5) + v[1], v[2]]);
            let k = uni(rng, 0.3, 1.0);
            nrm = nrm.map(|c| c * alpha * k);
            let mut p = CompositePixel {
                scat: [uni(rng, 0.0, 1.0), uni(rng, 0.0, 1.0), uni(rng, 0.0, 1.0)],
                a: [uni(rng, 0.0, alpha), uni(rng, 0.0, alpha), uni(rng, 0.0, alpha)],
                r: uni(rng, 0.0, alpha),
                f0s: [uni(rng, 0.0, alpha), uni(rng, 0.0, alpha), uni(rng, 0.0, alpha)],
                alpha,
                normal: nrm,
                v,
            };
            match i {
                0 => {
                    p.a = [0.0; 3];
                    p.r = 0.0;
                    p.f0s = [0.0; 3];
                    p.alpha = 0.0;
                    p.normal = [0.0; 3];
                }
                1 => p.normal = norm([v[1], -v[0], 0.0]).map(|c| 0.7 * c),
                2 => p.normal = v.map(|c| 0.9 * c),
                3 => p.normal = [0.0; 3],
                _ => {}
            }
            p
        })
        .collect()
}

/// The reflection render's planes (channels of `fresnel`) and the
/// scattering colour planes for these pixels; extra planes get `extra`.
fn planes(px: &[CompositePixel], fresnel: Fresnel, extra: &mut Rng) -> (Vec<f32>, Vec<f32>) {
    let n = px.len();
    let ch = fresnel.channels();
    let mut refl = vec![0f32; Plane::count(ch) as usize * n];
    let mut scat = vec![0f32; 3 * n];
    for (i, p) in px.iter().enumerate() {
        let mut set = |plane: u32, v: f64| refl[plane as usize * n + i] = v as f32;
        for c in 0..3 {
            set(c, p.a[c as usize]);
        }
        set(3, p.r);
        if ch == 7 {
            for c in 0..3 {
                set(4 + c, p.f0s[c as usize]);
            }
        }
        set(Plane::Alpha.index(ch), p.alpha);
        set(Plane::Depth.index(ch), p.alpha * uni(extra, 1.0, 3.0));
        for k in 0..3 {
            set(Plane::Normal(k).index(ch), p.normal[k as usize]);
        }
        set(Plane::Median.index(ch), uni(extra, 1.0, 3.0));
        set(Plane::Distortion.index(ch), uni(extra, 0.0, 0.1));
        for c in 0..3 {
            scat[c * n + i] = p.scat[c] as f32;
        }
    }
    (scat, refl)
}

fn gpu_composite(cam: &Camera, fresnel: Fresnel, scat: &[f32], refl: &[f32], g_in: &[f32], (prior, mask): (CompositePriors, Option<&[f32]>)) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let ctx = ctx_shared();
    let shading = ReflectionShading::new(ctx).unwrap();
    let n = (cam.width * cam.height) as usize;
    let s = Buffer::from_slice(ctx, "test.scat", scat).unwrap();
    let r = Buffer::from_slice(ctx, "test.refl", refl).unwrap();
    let li = Buffer::<f32>::new(ctx, "test.loss_in", 10 * n).unwrap();
    let gi = Buffer::from_slice(ctx, "test.loss_grad", g_in).unwrap();
    let gr = Buffer::<f32>::new(ctx, "test.refl_grad", refl.len()).unwrap();
    let gs = Buffer::<f32>::new(ctx, "test.scat_grad", 3 * n).unwrap();
    let m = mask.map(|m| Buffer::from_slice(ctx, "test.mask", m).unwrap());
    let mut rec = Recorder::new(ctx).unwrap();
    let inputs = tgs_pipelines::reflection::CompositeInputs { scat: &s, refl: &r };
    shading.record_composite(&mut rec, cam, fresnel, &inputs, &li).unwrap();
    let grads = tgs_pipelines::reflection::CompositeGrads { loss_grad: &gi, refl_grad: &gr, scat_grad: Some(&gs), mask: m.as_ref() };
    shading.record_composite_backward(&mut rec, cam, fresnel, &inputs, &grads, prior).unwrap();
    rec.submit_and_wait().unwrap();
    (li.download().unwrap(), gr.download().unwrap(), gs.download().unwrap())
}

#[test]
fn composite_matches_reference_and_finite_differences() {
    let mut rng = Rng(seed("composite"));
    for (w, h) in [(7u32, 5u32), (1, 1)] {
        let cam = comp_camera(w, h);
        let n = (w * h) as usize;
        for fresnel in [Fresnel::Off, Fresnel::Schlick] {
            let schlick = fresnel == Fresnel::Schlick;
            let ch = fresnel.channels();
            let px = composite_inputs(&mut rng, &cam);
            // Round the inputs to f32 once; the reference uses those values.
            let (scat, refl) = planes(&px, fresnel, &mut rng);
            let px: Vec<CompositePixel> = (0..n)
                .map(|i| {
                    let g = |p: u32| refl[p as usize * n + i] as f64;
                    CompositePixel {
                        scat: [0, 1, 2].map(|c| scat[c * n + i] as f64),
                        a: [g(0), g(1), g(2)],
                        r: g(3),
                        f0s: if ch == 7 { [g(4), g(5), g(6)] } else { [0.0; 3] },
                        alpha: g(Plane::Alpha.index(ch)),
                        normal: [0, 1, 2].map(|k| g(Plane::Normal(k).index(ch))),
                        v: px[i].v,
                    }
                })
                .collect();
            let g_in: Vec<f32> = (0..10 * n).map(|_| uni(&mut rng, -1.0, 1.0) as f32).collect();
            // The loss also holds r * R + alpha * alpha per pixel (penalties
            // on the means of R and of the reflection set's alpha), and with
            // a glass mask m mask / 2 (alpha - m)^2 (a weight without a mask
            // is ignored).
            let prior = CompositePriors { r: uni(&mut rng, 0.1, 0.5) as f32, alpha: uni(&mut rng, 0.1, 0.5) as f32, mask: uni(&mut rng, 0.1, 0.5) as f32 };
            let glass: Vec<f32> = (0..n).map(|_| if uni(&mut rng, 0.0, 1.0) < 0.5 { 1.0 } else { 0.0 }).collect();
            let with_mask = w > 1 && fresnel == Fresnel::Schlick;
            let mask = with_mask.then_some(&glass[..]);
            let (li, gr, gs) = gpu_composite(&cam, fresnel, &scat, &refl, &g_in, (prior, mask));
            for (name, v) in [("composite", &li), ("reflection gradient", &gr), ("scattering gradient", &gs)] {
                assert!(v.iter().all(|x| x.is_finite()), "{fresnel:?} {w}x{h}: non-finite {name}");
            }
            for i in 0..n {
                let want = rr::composite(&px[i], schlick);
                for c in 0..3 {
                    assert!((li[c * n + i] as f64 - want[c]).abs() < 1e-5, "{fresnel:?} pixel {i} channel {c}: GPU {} vs f64 {}", li[c * n + i], want[c]);
                }
                // Pass-through planes.
                for k in 0..7u32 {
                    assert_eq!(li[(3 + k) as usize * n + i], refl[(ch + k) as usize * n + i], "plane {k} of pixel {i} not passed through");
                }
                // Gradients: d(sum_c g_c I_c)/d(input) by central differences.
                let loss = |p: &CompositePixel| {
                    let v = rr::composite(p, schlick);
                    let to_mask = mask.map_or(0.0, |m| 0.5 * prior.mask as f64 * (p.alpha - m[i] as f64).powi(2));
                    (0..3).map(|c| v[c] * g_in[c * n + i] as f64).sum::<f64>() + prior.r as f64 * p.r + prior.alpha as f64 * p.alpha + to_mask
                };
                let step = 1e-7;
                let fd = |f: &dyn Fn(&mut CompositePixel, f64)| {
                    let (mut a, mut b) = (px[i], px[i]);
                    f(&mut a, step);
                    f(&mut b, -step);
                    (loss(&a) - loss(&b)) / (2.0 * step)
                };
                let mut checks: Vec<(String, f64, f32)> = Vec::new();
                for c in 0..3 {
                    checks.push((format!("scat[{c}]"), fd(&|p, e| p.scat[c] += e), gs[c * n + i]));
                    checks.push((format!("A[{c}]"), fd(&|p, e| p.a[c] += e), gr[c * n + i]));
                }
                checks.push(("R".into(), fd(&|p, e| p.r += e), gr[3 * n + i]));
                // The hard-case pixels sit on the clamp's kinks (cos = 0 or
                // 1) or at zero coverage, where only one-sided derivatives
                // exist: values and finiteness are checked above.
                // Without Schlick alpha enters only through the area prior.
                let ga = g_in[3 * n + i] as f64;
                if !schlick || i > 3 {
                    checks.push(("alpha".into(), fd(&|p, e| p.alpha += e) + ga, gr[Plane::Alpha.index(ch) as usize * n + i]));
                }
                if schlick && i > 3 {
                    for c in 0..3 {
                        checks.push((format!("F0 sum[{c}]"), fd(&|p, e| p.f0s[c] += e), gr[(4 + c) * n + i]));
                    }
                    for k in 0..3u32 {
                        let gn = g_in[(5 + k) as usize * n + i] as f64;
                        checks.push((format!("normal[{k}]"), fd(&|p, e| p.normal[k as usize] += e) + gn, gr[Plane::Normal(k).index(ch) as usize * n + i]));
                    }
                }
                for (name, want, got) in checks {
                    assert!((got as f64 - want).abs() <= 1e-4 * (1.0 + want.abs()), "{fresnel:?} {w}x{h} pixel {i} d/d{name}: GPU {got} vs FD {want}");
                }
                // Depth, median, distortion pass their gradients through.
                for (p, k) in [(Plane::Depth, 4u32), (Plane::Median, 8), (Plane::Distortion, 9)] {
                    assert_eq!(gr[p.index(ch) as usize * n + i], g_in[k as usize * n + i], "{p:?} gradient of pixel {i}");
                }
            }
        }
    }
    check_validation(ctx_shared());
}
