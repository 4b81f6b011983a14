//! Arrays larger than one storage binding (the SH 3 features of a million
//! Gaussians are 183 MiB; lavapipe binds 128) are bound in slices by the
//! projection and the reduce, Adam's own pass and the densification's
//! copy: each forced here on small sets, against the whole binding, bit for
//! bit.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Adam, Densifier, DensifyParams, HostGaussians, TrainableSet};
use tgs_tests::train_cases::{densify_cases as cases, fused_case, FusedCase};
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

/// A set whose features exceed one storage binding (a million Gaussians of
/// SH degree 3 on lavapipe) is projected and reduced in slices of
/// Gaussians, each binding its part of the features and of their moments
/// or gradients (`Rasterizer::feature_slices`). Forced here on 400 Gaussians
/// in slices of 64 (the last one partial): the image, the densification
/// gradients, the parameters, moments and gradients come out bit for bit
/// as with the whole buffers bound, for the plain backward, the fused
/// reduce and Adam, and its feature-only variant.
#[test]
fn features_bound_in_slices_give_the_whole_bindings_results() {
    use tgs_pipelines::{Features, Rasterizer};
    let ctx = ctx_shared();
    let sh3 = Features::Sh { degree: 3 };
    let FusedCase { host, cam, grad_out, adam, groups } = fused_case("features_bound_in_slices_give_the_whole_bindings_results");
    let bits = |b: &Buffer<f32>| -> Vec<u32> { b.download().unwrap().iter().map(|v| v.to_bits()).collect() };
    // 0: backward then Adam's pass; 1: the fused reduce; 2: its feature-only variant.
    for mode in 0..3 {
        let run = |slice: Option<u32>| -> Vec<(String, Vec<u32>)> {
            let rast = Rasterizer::new(ctx, 3, sh3).unwrap();
            let rast = match slice {
                Some(s) => rast.feature_slice(s),
                None => rast,
            };
            if mode > 0 && !rast.can_fuse_adam() {
                return Vec::new();
            }
            let set = TrainableSet::new(ctx, &host).unwrap();
            let mut frame = rast.frame(cam.width, cam.height, set.len(), 1024).unwrap();
            let mut out = Vec::new();
            for t in 1..=2u64 {
                rast.forward(&set.params, &cam, &[0.1, 0.5, 0.9], 3, &mut frame, false).unwrap();
                out.push((format!("step {t}: image"), bits(&frame.out)));
                frame.grad_out.upload(&grad_out).unwrap();
                let mut rec = Recorder::new(ctx).unwrap();
                if mode == 0 {
                    rast.record_backward(&mut rec, &set.params, &set.grads, 3, &frame).unwrap();
                    adam.record_set(&mut rec, &set, &groups, t).unwrap();
                } else {
                    let c = adam.reduce_constants(&set, &groups, t).unwrap();
                    rast.record_backward_adam(&mut rec, &set.params, tgs_pipelines::Moments { m: &set.m, v: &set.v, adam: &c, features_only: mode == 2 }, 3, &frame, None).unwrap();
                }
                rec.submit_and_wait().unwrap();
                out.push((format!("step {t}: densify"), bits(&frame.densify)));
            }
            out.extend(set.arrays().into_iter().map(|(name, b, _)| (name, bits(b))));
            out
        };
        let (whole, sliced) = (run(None), run(Some(64)));
        assert_eq!(whole.len(), sliced.len());
        for ((name, a), (_, b)) in whole.iter().zip(&sliced) {
            assert!(a == b, "mode {mode}: {name} differs between whole and sliced feature bindings");
        }
        if let Some((_, f)) = whole.iter().find(|(n, _)| n == "param.features") {
            assert_ne!(*f, bits(&TrainableSet::new(ctx, &host).unwrap().params.features), "mode {mode}: the features did not move");
        }
    }
    check_validation(ctx);
}

/// Adam's own pass (the GPU default) steps an array that exceeds one
/// storage binding in slices of whole blocks (the SH 3 features of a
/// million Gaussians on lavapipe). Forced here in slices of 64 Gaussians'
/// features on 400: two steps at SH degree 1 of 3 (the active
/// coefficients only, DC and rest at their own rates), direct and gated
/// (the whole array's grid read on the device), leave the parameters and
/// moments bit for bit as the whole step does.
#[test]
fn adam_in_slices_matches_the_whole_step() {
    let ctx = ctx_shared();
    let FusedCase { host, adam, groups, .. } = fused_case("adam_in_slices_matches_the_whole_step");
    let mut rng = Rng(seed("adam_in_slices_matches_the_whole_step grads"));
    let lens: Vec<usize> = TrainableSet::new(ctx, &host).unwrap().grads.buffers().iter().map(|b| b.len()).collect();
    let grads: Vec<Vec<f32>> = lens.iter().map(|&n| (0..n).map(|_| ((rng.next_u64() >> 40) as f32 / (1u64 << 24) as f32) - 0.5).collect()).collect();
    let bits = |b: &Buffer<f32>| -> Vec<u32> { b.download().unwrap().iter().map(|v| v.to_bits()).collect() };
    // 64 Gaussians' 48 features a slice: the features in 7 slices.
    let sliced = Adam::new(ctx, adam.eps).unwrap().slice(64 * 48);
    for gated in [false, true] {
        let run = |a: &Adam| -> Vec<(String, Vec<u32>)> {
            let set = TrainableSet::new(ctx, &host).unwrap();
            for (b, g) in set.grads.buffers().into_iter().zip(&grads) {
                b.upload(g).unwrap();
            }
            let grids = a.set_grids(&set, &groups);
            let args = Buffer::from_slice(ctx, "args", &grids.iter().flatten().copied().collect::<Vec<u32>>()).unwrap();
            let slots: Vec<_> = (0..5).map(|k| args.slice(3 * k, 3)).collect();
            for t in 1..=2u64 {
                let mut rec = Recorder::new(ctx).unwrap();
                if gated {
                    a.record_set_gated(&mut rec, &set, &groups, t, &slots).unwrap();
                } else {
                    a.record_set(&mut rec, &set, &groups, t).unwrap();
                }
                rec.submit_and_wait().unwrap();
            }
            set.arrays().into_iter().map(|(name, b, _)| (name, bits(b))).collect()
        };
        let (whole, parts) = (run(&adam), run(&sliced));
        for ((name, a), (_, b)) in whole.iter().zip(&parts) {
            assert!(a == b, "gated {gated}: {name} differs between the whole and the sliced step");
        }
        let f = whole.iter().find(|(n, _)| n == "param.features").unwrap();
        assert_ne!(f.1, bits(&TrainableSet::new(ctx, &host).unwrap().params.features), "gated {gated}: the features did not move");
    }
    check_validation(ctx);
}

/// Densification copies an array that exceeds one storage binding (the SH
/// 3 features of a million Gaussians on lavapipe) in slices of source
/// Gaussians, each slice's outputs bound from an aligned float before
/// their start. Forced here in slices of 64 on 320 Gaussians (the eight
/// cases forty times: clones, splits and prunes in every slice): the
/// parameters, moments and counts come out bit for bit as the whole copy's.
#[test]
fn densify_in_slices_matches_the_whole_copy() {
    let ctx = ctx_shared();
    let (g8, acc8, den8, rad8) = cases();
    let mut g = HostGaussians::new(3, 4);
    let (mut acc, mut den, mut rad) = (vec![], vec![], vec![]);
    for r in 0..40 {
        for i in 0..8 {
            let s = |v: &[f32], w: usize| -> Vec<f32> { v[w * i..w * (i + 1)].to_vec() };
            let mean = s(&g8.means, 3);
            g.push([mean[0] + r as f32, mean[1], mean[2]], s(&g8.log_scales, 2).try_into().unwrap(), s(&g8.quats, 4).try_into().unwrap(), g8.opacity[i], &s(&g8.features, 12));
            acc.push(acc8[i]);
            den.push(den8[i]);
            rad.push(rad8[i]);
        }
    }
    let run = |d: &Densifier| {
        let mut set = TrainableSet::new(ctx, &g).unwrap();
        set.accum.upload(&acc).unwrap();
        set.denom.upload(&den).unwrap();
        set.max_radii.upload(&rad).unwrap();
        for (k, (m, v)) in set.m.buffers().into_iter().zip(set.v.buffers()).enumerate() {
            let vals: Vec<f32> = (0..m.len()).map(|j| j as f32 + 0.25 * k as f32).collect();
            m.upload(&vals).unwrap();
            v.upload(&vals.iter().map(|x| -x).collect::<Vec<_>>()).unwrap();
        }
        let p = DensifyParams { grad_threshold: 2e-4, dense_scale: 0.01 * 5.0, opacity_min: 0.05, prune_big: true, big_screen: 20.0, big_world: 0.1 * 5.0, grow: true, seed: 11 };
        let r = d.densify(&mut set, &p).unwrap();
        (r, set.params.download().unwrap(), set.m.download().unwrap(), set.v.download().unwrap())
    };
    let whole = run(&Densifier::new(ctx).unwrap());
    let sliced = run(&Densifier::new(ctx).unwrap().slice(64));
    assert_eq!(whole.0, tgs_pipelines::DensifyReport { before: 320, after: 320 });
    assert!(whole == sliced, "the sliced densification differs from the whole one");
    check_validation(ctx);
}
