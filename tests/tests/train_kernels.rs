//! Adam and adaptive density control on the GPU against CPU expectations.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Adam, AdamArrays, AdamGroup, Densifier, DensifyParams, Guard, HostGaussians, TrainableSet};
use tgs_tests::train_cases::{densify_cases as cases, fused_case, fused_case_of, fused_groups, FusedCase};
use tgs_tests::Rng;
use tgs_tests::{check_validation, ctx_shared, seed};

#[test]
fn adam_matches_f64_reference_and_ignores_non_finite_gradients() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("adam_matches_f64_reference"));
    let n = 1000;
    let group = AdamGroup::split(0.01, 0.001, 4, 1);
    let adam = Adam::new(ctx, 1e-15).unwrap();
    let p0: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let (param, grad, m, v) =
        (Buffer::from_slice(ctx, "p", &p0).unwrap(), Buffer::<f32>::new(ctx, "g", n).unwrap(), Buffer::<f32>::new(ctx, "m", n).unwrap(), Buffer::<f32>::new(ctx, "v", n).unwrap());
    let (mut p, mut m64, mut v64) = (p0.iter().map(|&x| x as f64).collect::<Vec<_>>(), vec![0f64; n], vec![0f64; n]);
    for t in 1..=6u64 {
        let mut g: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32 * if rng.below(10) == 0 { 0.0 } else { 1.0 }).collect();
        g[7] = f32::NAN;
        g[11] = f32::INFINITY;
        grad.upload(&g).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        adam.record(&mut rec, AdamArrays { param: &param, grad: &grad, m: &m, v: &v, n }, &group, t).unwrap();
        rec.submit_and_wait().unwrap();
        let (b1, b2) = (0.9f64, 0.999f64);
        for i in 0..n {
            let gi = if g[i].is_finite() { g[i] as f64 } else { 0.0 };
            m64[i] = b1 * m64[i] + (1.0 - b1) * gi;
            v64[i] = b2 * v64[i] + (1.0 - b2) * gi * gi;
            let lr = if i % 4 < 1 { 0.01 } else { 0.001 };
            let denom = v64[i].sqrt() / (1.0 - b2.powi(t as i32)).sqrt() + 1e-15;
            p[i] -= lr / (1.0 - b1.powi(t as i32)) * m64[i] / denom;
        }
    }
    let got = param.download().unwrap();
    for i in 0..n {
        assert!((got[i] as f64 - p[i]).abs() < 2e-6, "element {i}: GPU {} vs reference {}", got[i], p[i]);
    }
    assert!(got.iter().all(|v| v.is_finite()));
    check_validation(ctx);
}

fn densify(seed_value: u32) -> (HostGaussians, HostGaussians, HostGaussians, [Vec<f32>; 3]) {
    let ctx = ctx_shared();
    let (g, acc, den, rad) = cases();
    let mut set = TrainableSet::new(ctx, &g).unwrap();
    set.accum.upload(&acc).unwrap();
    set.denom.upload(&den).unwrap();
    set.max_radii.upload(&rad).unwrap();
    // Moments: recognisable values per Gaussian.
    let mut mh = g.clone();
    for (k, arr) in [&mut mh.means, &mut mh.log_scales, &mut mh.quats, &mut mh.opacity, &mut mh.features].into_iter().enumerate() {
        let w = arr.len() / 8;
        for (j, v) in arr.iter_mut().enumerate() {
            *v = 100.0 * (j / w + 1) as f32 + k as f32;
        }
    }
    for (dst, src) in [(&set.m, &mh), (&set.v, &mh)] {
        dst.means.upload(&src.means).unwrap();
        dst.log_scales.upload(&src.log_scales).unwrap();
        dst.quats.upload(&src.quats).unwrap();
        dst.opacity.upload(&src.opacity).unwrap();
        dst.features.upload(&src.features).unwrap();
    }
    let d = Densifier::new(ctx).unwrap();
    let p =
        DensifyParams { grad_threshold: 2e-4, dense_scale: 0.01 * 5.0, opacity_min: 0.05, prune_big: true, big_screen: 20.0, big_world: 0.1 * 5.0, grow: true, seed: seed_value };
    let r = d.densify(&mut set, &p).unwrap();
    assert_eq!((r.before, r.after), (8, 8), "kept 0, 6 (2) + clone 1 (2) + split 2, 7 (4) = 8");
    check_validation(ctx);
    let stats = [set.accum.download().unwrap(), set.denom.download().unwrap(), set.max_radii.download().unwrap()];
    (set.params.download().unwrap(), set.m.download().unwrap(), set.v.download().unwrap(), stats)
}

#[test]
fn densify_clones_splits_and_prunes() {
    let (g, _, _, _) = cases();
    let (out, m, v, stats) = densify(7);
    // Output order follows the input: 0, 1, 1', 2a, 2b, 6, 7a, 7b.
    let src = [0usize, 1, 1, 2, 2, 6, 7, 7];
    let fresh = [false, false, true, true, true, false, true, true];
    let split = [false, false, false, true, true, false, true, true];
    for (o, (&s, (&is_new, &is_split))) in src.iter().zip(fresh.iter().zip(&split)).enumerate() {
        assert_eq!(out.opacity[o], g.opacity[s], "output {o}: opacity of {s}");
        assert_eq!(&out.quats[4 * o..4 * o + 4], &g.quats[4 * s..4 * s + 4]);
        assert_eq!(&out.features[12 * o..12 * o + 12], &g.features[12 * s..12 * s + 12]);
        for k in 0..2 {
            let want = g.log_scales[2 * s + k] - if is_split { 1.6f32.ln() } else { 0.0 };
            assert!((out.log_scales[2 * o + k] - want).abs() < 1e-6, "output {o}: log-scale {} vs {want}", out.log_scales[2 * o + k]);
        }
        let d: Vec<f32> = (0..3).map(|k| out.means[3 * o + k] - g.means[3 * s + k]).collect();
        if is_split {
            // Offset in the splat's plane: orthogonal to t_w (third column of R).
            let q = &g.quats[4 * s..4 * s + 4];
            let l = q.iter().map(|x| x * x).sum::<f32>().sqrt();
            let (r, x, y, z) = (q[0] / l, q[1] / l, q[2] / l, q[3] / l);
            let tw = [2.0 * (x * z + r * y), 2.0 * (y * z - r * x), 1.0 - 2.0 * (x * x + y * y)];
            let dot: f32 = (0..3).map(|k| d[k] * tw[k]).sum();
            let len = d.iter().map(|v| v * v).sum::<f32>().sqrt();
            let smax = g.log_scales[2 * s].max(g.log_scales[2 * s + 1]).exp();
            assert!(dot.abs() < 1e-5 && len > 0.0 && len < 6.0 * smax, "output {o}: split offset {d:?} (normal component {dot}, scale {smax})");
        } else {
            assert!(d.iter().all(|&v| v == 0.0), "output {o}: mean moved");
        }
        for (name, mom) in [("m", &m), ("v", &v)] {
            let want = if is_new { 0.0 } else { 100.0 * (s + 1) as f32 + 3.0 };
            assert_eq!(mom.opacity[o], want, "output {o}: Adam {name} of the opacity");
            let want = if is_new { 0.0 } else { 100.0 * (s + 1) as f32 + 4.0 };
            assert!(mom.features[12 * o..12 * o + 12].iter().all(|&x| x == want), "output {o}: Adam {name} of the features");
        }
    }
    assert!(stats.iter().all(|s| s.iter().all(|&x| x == 0.0)), "statistics start at zero after densification");
    // Deterministic per seed; another seed moves the split children.
    let (again, _, _, _) = densify(7);
    assert_eq!(out, again);
    let (other, _, _, _) = densify(8);
    assert_ne!(out.means, other.means);
}

#[test]
fn densify_prune_only_and_empty_result() {
    let ctx = ctx_shared();
    let (g, acc, den, rad) = cases();
    let d = Densifier::new(ctx).unwrap();
    let mut set = TrainableSet::new(ctx, &g).unwrap();
    set.accum.upload(&acc).unwrap();
    set.denom.upload(&den).unwrap();
    set.max_radii.upload(&rad).unwrap();
    let p = DensifyParams { grad_threshold: 2e-4, dense_scale: 0.05, opacity_min: 0.05, prune_big: false, big_screen: 20.0, big_world: 0.5, grow: false, seed: 1 };
    let r = d.densify(&mut set, &p).unwrap();
    assert_eq!(r.after, 7, "only the transparent Gaussian goes without growth or size pruning");
    // Everything below the opacity threshold: an empty set, then still usable.
    let p = DensifyParams { opacity_min: 0.99, ..p };
    let r = d.densify(&mut set, &p).unwrap();
    assert_eq!(r.after, 0);
    assert!(set.is_empty());
    let r = d.densify(&mut set, &p).unwrap();
    assert_eq!((r.before, r.after), (0, 0));
    check_validation(ctx);
}

#[test]
fn opacity_reset_caps_opacity_and_clears_its_moments() {
    let ctx = ctx_shared();
    let (g, _, _, _) = cases();
    let set = TrainableSet::new(ctx, &g).unwrap();
    let ones = vec![1.0f32; 8];
    set.m.opacity.upload(&ones).unwrap();
    set.v.opacity.upload(&ones).unwrap();
    set.m.means.upload(&[1.0f32; 24]).unwrap();
    let d = Densifier::new(ctx).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    d.record_opacity_reset(&mut rec, &set, 0.01).unwrap();
    rec.submit_and_wait().unwrap();
    let cap = (0.01f32 / 0.99).ln();
    let got = set.params.opacity.download().unwrap();
    for (a, b) in got.iter().zip(&g.opacity) {
        assert_eq!(*a, b.min(cap));
    }
    assert!(set.m.opacity.download().unwrap().iter().chain(&set.v.opacity.download().unwrap()).all(|&x| x == 0.0));
    assert!(set.m.means.download().unwrap().iter().all(|&x| x == 1.0), "other moments untouched");
    check_validation(ctx);
}

/// Adam on the first `active` elements of each block (the SH coefficients
/// of the active degrees): the others are not touched, not even where their
/// gradient is non-zero; and where their gradient is zero (inactive SH
/// coefficients), the result equals stepping every element, bit for bit.
#[test]
fn adam_steps_only_the_active_elements_of_each_block() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("adam active"));
    let (blocks, stride, active) = (777usize, 48u32, 12u32);
    let n = blocks * stride as usize;
    let adam = Adam::new(ctx, 1e-15).unwrap();
    let p0: Vec<f32> = (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect();
    let live = |i: usize| (i % stride as usize) < active as usize;
    let grad_seed = rng.next_u64();
    let run = |group: AdamGroup, zero_inactive: bool| -> [Vec<u32>; 3] {
        let mut rng = Rng(grad_seed);
        let bufs = [Buffer::from_slice(ctx, "p", &p0).unwrap(), Buffer::<f32>::new(ctx, "m", n).unwrap(), Buffer::<f32>::new(ctx, "v", n).unwrap()];
        let grad = Buffer::<f32>::new(ctx, "g", n).unwrap();
        for t in 1..=3u64 {
            let g: Vec<f32> = (0..n).map(|i| if zero_inactive && !live(i) { 0.0 } else { rng.uniform(-1.0, 1.0) as f32 }).collect();
            grad.upload(&g).unwrap();
            let mut rec = Recorder::new(ctx).unwrap();
            adam.record(&mut rec, AdamArrays { param: &bufs[0], grad: &grad, m: &bufs[1], v: &bufs[2], n }, &group, t).unwrap();
            rec.submit_and_wait().unwrap();
        }
        bufs.map(|b| b.download().unwrap().iter().map(|v| v.to_bits()).collect())
    };
    let all = AdamGroup::split(0.01, 0.001, stride, 3);
    let some = AdamGroup { active, ..all };
    assert_eq!(some.items(n), blocks * active as usize);
    // Non-zero gradients everywhere: inactive elements keep their value and zero moments.
    let [p, m, v] = run(some, false);
    let [pa, ma, va] = run(all, false);
    for i in 0..n {
        if live(i) {
            assert_eq!((p[i], m[i], v[i]), (pa[i], ma[i], va[i]), "active element {i} differs from stepping everything");
        } else {
            assert_eq!((p[i], m[i], v[i]), (p0[i].to_bits(), 0, 0), "inactive element {i} was stepped");
        }
    }
    // Zero gradients where inactive: the same as stepping every element.
    assert!(run(some, true) == run(all, true), "skipping zero-gradient elements changed the result");
    // Blocks must be whole.
    let b = |name| Buffer::<f32>::new(ctx, name, 50).unwrap();
    let (p50, g50, m50, v50) = (b("p"), b("g"), b("m"), b("v"));
    assert!(adam.record(&mut Recorder::new(ctx).unwrap(), AdamArrays { param: &p50, grad: &g50, m: &m50, v: &v50, n: 50 }, &some, 1).is_err());
    check_validation(ctx);
}

/// The ways of reaching the gradient records this device has.
fn record_accesses(ctx: &tgs_engine::Context) -> Vec<tgs_pipelines::RecordAccess> {
    let mut access = vec![tgs_pipelines::RecordAccess::Binding];
    if ctx.caps().buffer_device_address {
        access.push(tgs_pipelines::RecordAccess::Address);
    }
    access
}

/// Every array of `set`, as bits.
fn bits_of(set: &TrainableSet) -> Vec<(String, Vec<u32>)> {
    set.arrays().into_iter().map(|(name, b, _)| (name, b.download().unwrap().iter().map(|v| v.to_bits()).collect())).collect()
}

/// Two steps of `rast` on a fresh set from `c`: the reduce with Adam fused
/// (`features_only` as given), or the backward (the colour backward when
/// `features_only`) then Adam's own pass. The arrays' bits after, preceded
/// by each step's densification gradients unless `features_only`.
fn two_steps(rast: &tgs_pipelines::Rasterizer, c: &FusedCase, fused: bool, features_only: bool) -> Vec<(String, Vec<u32>)> {
    let ctx = ctx_shared();
    let set = TrainableSet::new(ctx, &c.host).unwrap();
    let mut frame = rast.frame(c.cam.width, c.cam.height, set.len(), 1024).unwrap();
    let mut out = Vec::new();
    for t in 1..=2u64 {
        rast.forward(&set.params, &c.cam, &[0.1, 0.5, 0.9], 1, &mut frame, false).unwrap();
        frame.grad_out.upload(&c.grad_out).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        if fused {
            let k = c.adam.reduce_constants(&set, &c.groups, t).unwrap();
            rast.record_backward_adam(&mut rec, &set.params, tgs_pipelines::Moments { m: &set.m, v: &set.v, adam: &k, features_only }, 1, &frame, None).unwrap();
        } else if features_only {
            rast.record_backward_colour(&mut rec, &set.params, &set.grads, 1, &frame).unwrap();
            c.adam.record_set_features(&mut rec, &set, &c.groups[4], t).unwrap();
        } else {
            rast.record_backward(&mut rec, &set.params, &set.grads, 1, &frame).unwrap();
            c.adam.record_set(&mut rec, &set, &c.groups, t).unwrap();
        }
        rec.submit_and_wait().unwrap();
        if !features_only {
            let densify = frame.densify.download_range(0, 2 * set.len() as usize).unwrap();
            out.push((format!("step {t}: densify"), densify.iter().map(|v| v.to_bits()).collect()));
        }
    }
    out.extend(bits_of(&set));
    out
}

/// The per-Gaussian reduce with Adam fused (`Rasterizer::record_backward_adam`)
/// leaves bit for bit the parameters, moments and densification gradients
/// of the backward followed by Adam's own pass: two steps at SH degree 1 of
/// 3 (only the active coefficients stepped, DC and rest at their own
/// rates; the CPU reduce steps them four at a time, the inactive ones
/// rewritten as they were), and two of a set of degree 0 (3 features per
/// Gaussian, stepped one at a time), with the gradient records bound and
/// reached by address.
#[test]
fn the_reduce_with_adam_fused_matches_the_backward_then_adam() {
    use tgs_pipelines::{Features, RasterKernels, Rasterizer};
    let ctx = ctx_shared();
    for (degree, records) in [3, 0].into_iter().flat_map(|d| record_accesses(ctx).into_iter().map(move |r| (d, r))) {
        let FusedCase { host, cam, grad_out, adam, groups } = fused_case_of("the_reduce_with_adam_fused_matches_the_backward_then_adam", degree);
        let rast = Rasterizer::with_records(ctx, 3, Features::Sh { degree }, None, RasterKernels::for_device(ctx.caps()), records).unwrap();
        if !rast.can_fuse_adam() {
            eprintln!("{} cannot run the fused reduce: skipped", ctx.caps().device_name);
            return;
        }
        let case = FusedCase { host, cam, grad_out, adam, groups };
        let run = |fused: bool| two_steps(&rast, &case, fused, false);
        let (fused, separate) = (run(true), run(false));
        for ((name, a), (_, b)) in fused.iter().zip(&separate) {
            assert!(a == b, "{records:?}, SH degree {degree}: {name} differs between the fused and the separate step");
        }
        let params = |s: &[(String, Vec<u32>)], k: &str| s.iter().find(|a| a.0 == k).unwrap().1.clone();
        let initial = bits_of(&TrainableSet::new(ctx, &case.host).unwrap());
        for k in ["param.means", "param.log_scales", "param.quats", "param.opacity", "param.features"] {
            assert_ne!(params(&fused, k), params(&initial, k), "{records:?}: {k} did not move");
        }
    }
    check_validation(ctx);
}

/// The feature-only reduce with Adam fused (`Moments::features_only`: Stage
/// III's scattering colour on CPU devices) leaves bit for bit the
/// parameters and moments of the feature-only backward followed by Adam's
/// pass over the features (two steps at SH degree 1 of 3, records bound
/// and by address); the geometry and its moments stay as they were, and the
/// features move.
#[test]
fn the_feature_only_reduce_with_adam_matches_the_colour_backward_then_adam() {
    use tgs_pipelines::{Features, RasterKernels, Rasterizer};
    let ctx = ctx_shared();
    let sh3 = Features::Sh { degree: 3 };
    let case = fused_case("the_feature_only_reduce_with_adam_matches_the_colour_backward_then_adam");
    let initial = bits_of(&TrainableSet::new(ctx, &case.host).unwrap());
    for records in record_accesses(ctx) {
        let rast = Rasterizer::with_records(ctx, 3, sh3, None, RasterKernels::for_device(ctx.caps()), records).unwrap();
        if !rast.can_fuse_adam() {
            eprintln!("{} cannot run the fused reduce: skipped", ctx.caps().device_name);
            return;
        }
        let run = |fused: bool| two_steps(&rast, &case, fused, true);
        let (fused, separate) = (run(true), run(false));
        for (((name, a), (_, b)), (_, init)) in fused.iter().zip(&separate).zip(&initial) {
            if name.starts_with("grad.") {
                continue;
            }
            assert!(a == b, "{records:?}: {name} differs between the fused and the separate step");
            let feature = name.ends_with(".features");
            assert_eq!(a != init, feature, "{records:?}: {name} should {} move", if feature { "" } else { "not" });
        }
    }
    check_validation(ctx);
}

#[test]
fn the_fused_reduce_refuses_groups_it_cannot_express() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("the_fused_reduce_refuses_groups_it_cannot_express"));
    let sh3 = tgs_pipelines::Features::Sh { degree: 3 };
    let host = tgs_tests::raster_util::random_scene(&mut rng, &tgs_tests::raster_util::SceneSpec::new(20, 3, sh3));
    let adam = Adam::new(ctx, 1e-15).unwrap();
    let groups = fused_groups();
    // Groups the fused step cannot express are refused, not approximated.
    let set = TrainableSet::new(ctx, &host).unwrap();
    let mut two_rates = groups;
    two_rates[0] = AdamGroup::split(1e-3, 1e-4, 3, 1);
    assert!(adam.reduce_constants(&set, &two_rates, 1).is_err());
    let mut wrong_block = groups;
    wrong_block[4] = AdamGroup::split(1e-3, 1e-4, 12, 3);
    assert!(adam.reduce_constants(&set, &wrong_block, 1).is_err());
    check_validation(ctx);
}

/// The divergence guard against the host: a flag per array, set exactly
/// when a value is NaN, infinite or past its limit (a bad value first,
/// last, in the middle, at a window's edge), checked whole and in windows
/// of 64 (offsets of 256 bytes); a new round does not see the last
/// round's flags.
#[test]
fn guard_flags_exactly_the_arrays_with_bad_values() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("guard_flags_exactly"));
    let n = 1000;
    let limit = 50.0f32;
    let base: Vec<f32> = (0..n).map(|_| rng.uniform(-40.0, 40.0) as f32).collect();
    let bad = [(0, f32::NAN), (n - 1, f32::INFINITY), (500, f32::NEG_INFINITY), (64, 50.5), (63, -1e30), (128, f32::MAX)];
    let mut arrays = vec![base.clone(), vec![limit; n], vec![-limit; n]];
    for (i, v) in bad {
        let mut a = base.clone();
        a[i] = v;
        arrays.push(a);
    }
    let bufs: Vec<Buffer<f32>> = arrays.iter().map(|a| Buffer::from_slice(ctx, "guarded", a).unwrap()).collect();
    let host: Vec<usize> = arrays.iter().enumerate().filter(|(_, a)| a.iter().any(|v| !(v.abs() <= limit))).map(|(k, _)| k).collect();
    assert_eq!(host, (3..arrays.len()).collect::<Vec<_>>());
    for guard in [Guard::new(ctx, bufs.len()).unwrap(), Guard::new(ctx, bufs.len()).unwrap().window(64)] {
        for round in 0..2 {
            let mut rec = Recorder::new(ctx).unwrap();
            guard.next_round();
            for (k, b) in bufs.iter().enumerate() {
                // Round 1 checks only the clean arrays: the flags of round 0 must not stay.
                let n_checked = if round == 0 || k < 3 { n } else { 0 };
                guard.record_check(&mut rec, b, n_checked, limit, k).unwrap();
            }
            guard.record_read(&mut rec).unwrap();
            rec.submit_and_wait().unwrap();
            assert_eq!(guard.tripped().unwrap(), if round == 0 { host.clone() } else { vec![] });
        }
    }
    // f32::MAX as the limit: only NaN and infinities trip.
    let guard = Guard::new(ctx, bufs.len()).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    guard.next_round();
    for (k, b) in bufs.iter().enumerate() {
        guard.record_check(&mut rec, b, n, f32::MAX, k).unwrap();
    }
    guard.record_read(&mut rec).unwrap();
    rec.submit_and_wait().unwrap();
    assert_eq!(guard.tripped().unwrap(), vec![3, 4, 5]);
    assert!(guard.record_check(&mut Recorder::new(ctx).unwrap(), &bufs[0], n, limit, bufs.len()).is_err());
    check_validation(ctx);
}
