//! A view's blend weights kept for a set whose geometry and opacity are
//! frozen (`pipelines/src/raster/kept_weights.rs`: Stage III's scattering
//! colour): the colour planes they give are the full forward's bit for
//! bit; the colour gradients are the colour-only tile backward's up to
//! the order of the sums, and match finite differences of the f64
//! reference; the fused Adam step from them steps the colour alone; reruns
//! are bit-identical; a set of plain features (the reflection set's
//! layout) keeps its geometry planes and renders every plane as the full
//! forward; an empty view, a one-pixel view, several passes per kernel, a
//! budget too small and a mismatched set or frame are handled.

use tgs_engine::Recorder;
use tgs_pipelines::{Camera, Features, Frame, Gaussians, KeptWeights, Moments, RasterKernels, Rasterizer, RecordAccess, TrainableSet};
use tgs_tests::raster_ref::{self, RefScene};
use tgs_tests::raster_util::{random_scene, SceneSpec};
use tgs_tests::train_cases::{fused_case, FusedCase};
use tgs_tests::{check_validation, ctx_shared, seed, Rng};

const BG: [f32; 3] = [0.1, 0.5, 0.9];

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn colour_planes(frame: &Frame) -> Vec<f32> {
    frame.out.download_range(0, 3 * (frame.width * frame.height) as usize).unwrap()
}

/// A full forward of `cam`, then its weights kept (no budget).
fn keep(rast: &Rasterizer, g: &Gaussians, cam: &Camera, frame: &mut Frame) -> KeptWeights {
    rast.forward(g, cam, &BG, 3, frame, false).unwrap();
    rast.keep_weights(g, frame, u64::MAX, false).unwrap().expect("the weights fit an unlimited budget")
}

/// The colour planes of `cam` from kept weights.
fn colour_from(rast: &Rasterizer, g: &Gaussians, cam: &Camera, frame: &Frame, k: &KeptWeights) -> Vec<f32> {
    let mut rec = Recorder::new(ctx_shared()).unwrap();
    rast.record_forward_weights(&mut rec, tgs_pipelines::Splats::own(g, 3), cam, &BG, frame, k).unwrap();
    rec.submit_and_wait().unwrap();
    colour_planes(frame)
}

/// The feature and position gradients of `grad_out` on the colour planes:
/// from kept weights (after [`colour_from`]) or from a full forward and
/// the colour-only tile backward.
fn colour_grads(rast: &Rasterizer, set: &TrainableSet, cam: &Camera, frame: &Frame, grad_out: &[f32], k: Option<&KeptWeights>) -> (Vec<f32>, Vec<f32>) {
    let mut rec = Recorder::new(ctx_shared()).unwrap();
    match k {
        Some(k) => {
            frame.grad_out.upload(grad_out).unwrap();
            rast.record_backward_colour_weights(&mut rec, tgs_pipelines::Splats::own(&set.params, 3), &set.grads, &set.grads.features, frame, k).unwrap();
        }
        None => {
            rast.record_forward(&mut rec, &set.params, cam, &BG, 3, frame).unwrap();
            rec.submit_and_wait().unwrap();
            frame.grad_out.upload(grad_out).unwrap();
            rec = Recorder::new(ctx_shared()).unwrap();
            rast.record_backward_colour(&mut rec, &set.params, &set.grads, 3, frame).unwrap();
        }
    }
    rec.submit_and_wait().unwrap();
    (set.grads.features.download().unwrap(), set.grads.means.download().unwrap())
}

fn rel_err(a: &[f32], b: &[f32]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum();
    let n: f64 = b.iter().map(|y| (*y as f64).powi(2)).sum();
    (d / n.max(1e-30)).sqrt()
}

/// The image gradient on the colour planes only (the others zero: kept
/// weights take the colour's gradient alone).
fn colour_grad_out(grad_out: &[f32], pixels: usize) -> Vec<f32> {
    grad_out.iter().enumerate().map(|(i, g)| if i < 3 * pixels { *g } else { 0.0 }).collect()
}

/// Two views of 400 SH 3 Gaussians, in a frame that starts with room for
/// 16 intersections (it grows between them), with the default spans and
/// with spans of 32 (several capture passes, and several passes of the
/// colour and gradient kernels), after either tile forward (one subgroup
/// per tile, and the workgroup one GPUs run) and with the gradient records
/// bound and reached by address: after the colours change, the colour
/// planes from each view's kept weights are the full forward's bit for
/// bit, and their colour gradients the colour-only backward's to 1e-5.
#[test]
fn kept_weights_render_and_differentiate_the_colour_as_the_full_forward() {
    let ctx = ctx_shared();
    let FusedCase { host, cam, grad_out, .. } = fused_case("kept_weights_render_and_differentiate_the_colour_as_the_full_forward");
    let mut rng = Rng(seed("kept_weights_render_and_differentiate_the_colour_as_the_full_forward"));
    let cam_b = Camera::look_at([-1.2, 0.4, -3.5], [0.0, 0.1, 0.0], [0.0, -1.0, 0.1], 0.8, cam.width, cam.height);
    let pixels = (cam.width * cam.height) as usize;
    let grad_out = colour_grad_out(&grad_out, pixels);
    let features: Vec<f32> = host.features.iter().map(|f| f + 0.3 * (rng.uniform(-1.0, 1.0) as f32)).collect();
    let mut layouts = vec![
        (None, RasterKernels::for_device(ctx.caps()), RecordAccess::Binding),
        (Some(32), RasterKernels::Subgroup, RecordAccess::Binding),
        (None, RasterKernels::Workgroup, RecordAccess::Binding),
    ];
    if ctx.caps().buffer_device_address {
        layouts.push((None, RasterKernels::for_device(ctx.caps()), RecordAccess::Address));
    }
    for (span, kernels, records) in layouts {
        let Ok(rast) = Rasterizer::with_records(ctx, 3, Features::Sh { degree: 3 }, span, kernels, records) else {
            eprintln!("{} cannot run the {kernels:?} tile kernels: skipped", ctx.caps().device_name);
            continue;
        };
        let set = TrainableSet::new(ctx, &host).unwrap();
        let mut frame = rast.frame(cam.width, cam.height, set.len(), 16).unwrap();
        let kept: Vec<_> = [&cam, &cam_b].into_iter().map(|c| keep(&rast, &set.params, c, &mut frame)).collect();
        assert!(frame.capacity > 16, "the frame did not grow");
        assert!(kept.iter().all(|k| k.contributions() > 0));
        assert_ne!(kept[0].contributions(), kept[1].contributions());
        if span.is_some() {
            assert!(frame.spans > 1, "spans of 32 should split the tiles");
        }
        set.params.features.upload(&features).unwrap();
        for (v, (c, k)) in [&cam, &cam_b].into_iter().zip(&kept).enumerate() {
            rast.forward(&set.params, c, &BG, 3, &mut frame, false).unwrap();
            let full = colour_planes(&frame);
            let (g_full, m_full) = colour_grads(&rast, &set, c, &frame, &grad_out, None);
            let again = colour_from(&rast, &set.params, c, &frame, k);
            assert!(bits(&full) == bits(&again), "view {v} ({span:?}, {kernels:?}, {records:?}): the kept weights' colour differs from the full forward's");
            assert!(full.iter().any(|&x| x != BG[0] && x != BG[1] && x != BG[2]), "view {v} is empty");
            let (g_kept, m_kept) = colour_grads(&rast, &set, c, &frame, &grad_out, Some(k));
            assert!(g_kept.iter().chain(&m_kept).all(|x| x.is_finite()));
            let (ef, em) = (rel_err(&g_kept, &g_full), rel_err(&m_kept, &m_full));
            assert!(
                ef < 1e-5 && em < 1e-5,
                "view {v} ({span:?}, {kernels:?}, {records:?}): colour gradients from kept weights differ from the colour-only backward's: features {ef:.2e}, positions {em:.2e}"
            );
            assert!(g_full.iter().any(|&x| x != 0.0));
        }
    }
    check_validation(ctx);
}

/// The colour gradients from kept weights against central finite
/// differences of the f64 reference renderer (its loss sum(weights x
/// colour planes), random weights, zero on pixels the reference marks
/// ambiguous) over 200 random feature coefficients of Gaussians the view
/// sees: ||g - g_fd|| / ||g_fd|| <= 1e-3 (the loss is linear in the
/// coefficients away from the colour's clamp at zero, so the differences
/// are exact up to f64 rounding; the tolerance is the f32 sums').
#[test]
fn kept_weights_gradients_match_finite_differences_of_the_reference() {
    let ctx = ctx_shared();
    let FusedCase { host, cam, .. } = fused_case("kept_weights_gradients_match_finite_differences_of_the_reference");
    let mut rng = Rng(seed("kept_weights_gradients_match_finite_differences_of_the_reference"));
    let rast = Rasterizer::new(ctx, 3, Features::Sh { degree: 3 }).unwrap();
    let set = TrainableSet::new(ctx, &host).unwrap();
    let mut frame = rast.frame(cam.width, cam.height, set.len(), 4096).unwrap();
    let k = keep(&rast, &set.params, &cam, &mut frame);
    let base = RefScene::from_host(&host, false);
    let bg: Vec<f64> = BG.iter().map(|&b| b as f64).collect();
    let cpu = raster_ref::render(&base, &cam, &bg, 3);
    let pixels = (cam.width * cam.height) as usize;
    let planes = tgs_pipelines::Plane::count(3) as usize;
    let mut weights = vec![0.0f64; planes * pixels];
    for c in 0..3 {
        for i in 0..pixels {
            if cpu.gradient_checkable(i) {
                weights[c * pixels + i] = rng.uniform(-1.0, 1.0);
            }
        }
    }
    let grad_out: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    colour_from(&rast, &set.params, &cam, &frame, &k);
    let (g_kept, _) = colour_grads(&rast, &set, &cam, &frame, &grad_out, Some(&k));
    let seen: Vec<usize> = cpu.splats.iter().map(|s| s.index).collect();
    assert!(seen.len() > 50, "the view sees {} Gaussians", seen.len());
    let (mut d2, mut n2, mut checked) = (0.0f64, 0.0f64, 0);
    for _ in 0..200 {
        let g = seen[rng.below(seen.len() as u32) as usize];
        let i = g * 48 + rng.below(48) as usize;
        let eps = 1e-4;
        let mut s = RefScene::from_host(&host, false);
        s.features[i] += eps;
        let up = tgs_tests::raster_util::ref_loss(&s, &cam, &bg, 3, &weights);
        s.features[i] -= 2.0 * eps;
        let down = tgs_tests::raster_util::ref_loss(&s, &cam, &bg, 3, &weights);
        let fd = (up - down) / (2.0 * eps);
        d2 += (g_kept[i] as f64 - fd).powi(2);
        n2 += fd * fd;
        checked += (fd != 0.0) as usize;
    }
    assert!(checked > 50, "only {checked} of 200 coefficients move the loss");
    let err = (d2 / n2).sqrt();
    assert!(err <= 1e-3, "colour gradients from kept weights against finite differences of the reference: {err:.2e}");
    check_validation(ctx);
}

/// The fused Adam step of the colour from kept weights, twice, against
/// the same step after the colour-only tile backward: the features and
/// their moments agree to 1e-5, the geometry and its moments are not
/// touched (bit for bit), and a second run from the same start is
/// bit-identical to the first.
#[test]
fn the_colour_step_from_kept_weights_is_the_colour_only_step_and_reruns_bit_for_bit() {
    let ctx = ctx_shared();
    let FusedCase { host, cam, grad_out, adam, groups } = fused_case("the_colour_step_from_kept_weights_is_the_colour_only_step_and_reruns_bit_for_bit");
    let rast = Rasterizer::new(ctx, 3, Features::Sh { degree: 3 }).unwrap();
    if !rast.can_fuse_adam() {
        eprintln!("{} cannot run the fused reduce: skipped", ctx.caps().device_name);
        return;
    }
    let grad_out = colour_grad_out(&grad_out, (cam.width * cam.height) as usize);
    let run = |from_weights: bool| -> Vec<(String, Vec<f32>)> {
        let set = TrainableSet::new(ctx, &host).unwrap();
        let mut frame = rast.frame(cam.width, cam.height, set.len(), 1024).unwrap();
        let k = keep(&rast, &set.params, &cam, &mut frame);
        for t in 1..=2u64 {
            let mut rec = Recorder::new(ctx).unwrap();
            let c = adam.reduce_constants(&set, &groups, t).unwrap();
            let step = Moments { m: &set.m, v: &set.v, adam: &c, features_only: true };
            if from_weights {
                rast.record_forward_weights(&mut rec, tgs_pipelines::Splats::own(&set.params, 3), &cam, &BG, &frame, &k).unwrap();
                rec.submit_and_wait().unwrap();
                frame.grad_out.upload(&grad_out).unwrap();
                rec = Recorder::new(ctx).unwrap();
                rast.record_colour_adam_weights(&mut rec, &set.params, step, 3, &frame, &k).unwrap();
            } else {
                rast.forward(&set.params, &cam, &BG, 3, &mut frame, false).unwrap();
                frame.grad_out.upload(&grad_out).unwrap();
                rast.record_backward_adam(&mut rec, &set.params, step, 3, &frame, None).unwrap();
            }
            rec.submit_and_wait().unwrap();
        }
        let mut out = Vec::new();
        for (what, g) in [("param", &set.params), ("m", &set.m), ("v", &set.v)] {
            for (b, n) in g.buffers().iter().zip(["means", "log_scales", "quats", "opacity", "features"]) {
                out.push((format!("{what} {n}"), b.download().unwrap()));
            }
        }
        out
    };
    let (tiles, kept, again) = (run(false), run(true), run(true));
    let start = TrainableSet::new(ctx, &host).unwrap();
    let before: Vec<Vec<f32>> = start.params.buffers().iter().map(|b| b.download().unwrap()).collect();
    for (i, ((name, a), (_, b))) in tiles.iter().zip(&kept).enumerate() {
        assert!(b.iter().all(|x| x.is_finite()), "{name}: not finite");
        if name.ends_with("features") {
            let e = rel_err(b, a);
            assert!(e < 1e-5, "{name}: the step from kept weights differs from the colour-only step by {e:.2e}");
        } else {
            assert!(bits(a) == bits(b), "{name}: the colour step changed it");
            if i < 4 {
                assert!(bits(b) == bits(&before[i]), "{name}: the colour step moved the geometry");
            }
        }
    }
    for ((name, a), (_, b)) in kept.iter().zip(&again) {
        assert!(bits(a) == bits(b), "{name}: a rerun of the steps from kept weights differs");
    }
    check_validation(ctx);
}

/// Hard cases: a view that sees none of the Gaussians keeps no
/// contributions, renders the background exactly and has zero gradients;
/// a one-pixel view keeps its weights and renders as the full forward; a
/// budget below the weights' size keeps nothing; kept weights are refused,
/// by name, for a set of another size and a frame of another image size.
#[test]
fn kept_weights_of_empty_and_one_pixel_views_and_their_refusals() {
    let ctx = ctx_shared();
    let FusedCase { host, cam, .. } = fused_case("kept_weights_of_empty_and_one_pixel_views_and_their_refusals");
    let rast = Rasterizer::new(ctx, 3, Features::Sh { degree: 3 }).unwrap();
    let set = TrainableSet::new(ctx, &host).unwrap();

    let away = Camera::look_at([0.0, 0.0, -40.0], [0.0, 0.0, -80.0], [0.0, -1.0, 0.0], 0.8, cam.width, cam.height);
    let mut frame = rast.frame(cam.width, cam.height, set.len(), 1024).unwrap();
    let k = keep(&rast, &set.params, &away, &mut frame);
    assert_eq!(k.contributions(), 0);
    let colour = colour_from(&rast, &set.params, &away, &frame, &k);
    let pixels = (cam.width * cam.height) as usize;
    for c in 0..3 {
        assert!(colour[c * pixels..(c + 1) * pixels].iter().all(|&x| x == BG[c]), "an empty view from kept weights is not the background");
    }
    let ones = vec![1.0f32; tgs_pipelines::Plane::count(3) as usize * pixels];
    let (g, m) = colour_grads(&rast, &set, &away, &frame, &ones, Some(&k));
    assert!(g.iter().chain(&m).all(|&x| x == 0.0), "an empty view has gradients");

    let one = Camera { width: 1, height: 1, cx: 0.0, cy: 0.0, ..Camera::look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, -1.0, 0.0], 0.8, 1, 1) };
    let mut small = rast.frame(1, 1, set.len(), 64).unwrap();
    let k1 = keep(&rast, &set.params, &one, &mut small);
    let full = colour_planes(&small);
    assert!(bits(&colour_from(&rast, &set.params, &one, &small, &k1)) == bits(&full), "a one-pixel view from kept weights differs from the full forward");

    rast.forward(&set.params, &cam, &BG, 3, &mut frame, false).unwrap();
    assert!(rast.keep_weights(&set.params, &frame, 1024, false).unwrap().is_none(), "weights kept beyond a 1 KiB budget");
    let k = rast.keep_weights(&set.params, &frame, u64::MAX, false).unwrap().unwrap();
    assert!(k.bytes() > 1024);

    let fewer = Gaussians::upload(ctx, &{
        let mut h = tgs_pipelines::HostGaussians::new(3, 16);
        for i in 0..10 {
            h.push([0.1 * i as f32, 0.0, 0.0], [-2.0, -2.0], [1.0, 0.0, 0.0, 0.0], 0.5, &[0.2; 48]);
        }
        h
    })
    .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let e = rast.record_forward_weights(&mut rec, tgs_pipelines::Splats::own(&fewer, 3), &cam, &BG, &frame, &k).unwrap_err();
    assert!(e.to_string().contains("kept weights are of 400 Gaussians; the set has 10"), "{e}");
    let e = rast.record_backward_colour_weights(&mut rec, tgs_pipelines::Splats::own(&set.params, 3), &set.grads, &set.grads.features, &small, &k).unwrap_err();
    assert!(e.to_string().contains(&format!("kept weights are of a {}x{} view", cam.width, cam.height)), "{e}");
    drop(rec);
    check_validation(ctx);
}

/// A set of plain features with the reflection set's channel count (4),
/// its weights kept with its geometry planes for two views: after the
/// features change and the other view was rendered into the frame, each
/// view's render from its kept weights gives every plane of the full
/// forward bit for bit (colour from the weights, alpha to distortion
/// restored), the view fits its frame, and the feature gradients to a
/// separate buffer (the reflection set's `d_features`) are the colour-only
/// backward's to 1e-5.
#[test]
fn kept_weights_with_planes_render_every_plane_of_a_plain_feature_set() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("kept_weights_with_planes_render_every_plane_of_a_plain_feature_set"));
    let host = random_scene(&mut rng, &SceneSpec::new(300, 4, Features::Plain));
    let cam = tgs_tests::raster_util::default_camera(48, 40);
    let cam_b = Camera::look_at([-1.2, 0.4, -3.5], [0.0, 0.1, 0.0], [0.0, -1.0, 0.1], 0.8, cam.width, cam.height);
    let rast = Rasterizer::new(ctx, 4, Features::Plain).unwrap();
    let set = TrainableSet::new(ctx, &host).unwrap();
    let mut frame = rast.frame(cam.width, cam.height, set.len(), 1024).unwrap();
    let bg = [0.0f32; 4];
    let mut kept = Vec::new();
    for c in [&cam, &cam_b] {
        rast.forward(&set.params, c, &bg, 0, &mut frame, false).unwrap();
        kept.push(rast.keep_weights(&set.params, &frame, u64::MAX, true).unwrap().unwrap());
    }
    let without = {
        rast.forward(&set.params, &cam, &bg, 0, &mut frame, false).unwrap();
        rast.keep_weights(&set.params, &frame, u64::MAX, false).unwrap().unwrap()
    };
    let planes = tgs_pipelines::Plane::count(4) as u64 * (cam.width * cam.height) as u64;
    assert_eq!(kept[0].bytes(), without.bytes() + 4 * (planes - 4 * (cam.width * cam.height) as u64));
    let features: Vec<f32> = host.features.iter().map(|f| f + 0.3 * (rng.uniform(-1.0, 1.0) as f32)).collect();
    set.params.features.upload(&features).unwrap();
    let grad_out: Vec<f32> = (0..planes).map(|i| if i < 4 * (cam.width * cam.height) as u64 { rng.uniform(-1.0, 1.0) as f32 } else { 0.0 }).collect();
    let d_features = tgs_engine::Buffer::<f32>::new(ctx, "test.d_features", features.len()).unwrap();
    for (v, c) in [&cam, &cam_b].into_iter().enumerate() {
        rast.forward(&set.params, c, &bg, 0, &mut frame, false).unwrap();
        let full = frame.out.download().unwrap();
        frame.grad_out.upload(&grad_out).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        rast.record_backward_colour_with(&mut rec, tgs_pipelines::Splats::own(&set.params, 0), &set.grads, &d_features, &frame).unwrap();
        rec.submit_and_wait().unwrap();
        let g_full = d_features.download().unwrap();
        // The other view last: the frame holds none of this view's planes.
        let other = [&cam_b, &cam][v];
        rast.forward(&set.params, other, &bg, 0, &mut frame, false).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        rast.record_forward_weights(&mut rec, tgs_pipelines::Splats::own(&set.params, 0), c, &bg, &frame, &kept[v]).unwrap();
        rec.submit_and_wait().unwrap();
        assert!(rast.fit(&mut frame).unwrap(), "view {v}: a render from kept weights does not fit its frame");
        let again = frame.out.download().unwrap();
        assert!(bits(&full) == bits(&again), "view {v}: a render from kept weights with planes differs from the full forward");
        frame.grad_out.upload(&grad_out).unwrap();
        let mut rec = Recorder::new(ctx).unwrap();
        rast.record_backward_colour_weights(&mut rec, tgs_pipelines::Splats::own(&set.params, 0), &set.grads, &d_features, &frame, &kept[v]).unwrap();
        rec.submit_and_wait().unwrap();
        let e = rel_err(&d_features.download().unwrap(), &g_full);
        assert!(e < 1e-5, "view {v}: feature gradients from kept weights differ from the colour-only backward's by {e:.2e}");
        assert!(g_full.iter().any(|&x| x != 0.0));
    }
    check_validation(ctx);
}
