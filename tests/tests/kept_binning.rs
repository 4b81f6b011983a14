//! A view's binning kept for later forwards of the same geometry (Stage
//! III's frozen sets, `pipelines/src/raster/kept.rs`): the forward from the
//! kept binning renders and differentiates as the full forward does, bit
//! for bit, after the colours changed and the frame grew; a kept binning
//! of other Gaussians or another image size is refused by name.

use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Camera, Features, Gaussians, KeptBinning, Rasterizer, Splats, TrainableSet};
use tgs_tests::train_cases::{fused_case, FusedCase};
use tgs_tests::{check_validation, ctx_shared, Rng, seed};

fn bits(b: &Buffer<f32>) -> Vec<u32> {
    b.download().unwrap().iter().map(|v| v.to_bits()).collect()
}

/// The output planes, then the backward's gradients (full or colour-only)
/// and densification gradients of one view.
fn render_and_grads(rast: &Rasterizer, set: &TrainableSet, cam: &Camera, frame: &mut tgs_pipelines::Frame, grad_out: &[f32], kept: Option<&KeptBinning>, colour_only: bool) -> Vec<(String, Vec<u32>)> {
    let ctx = ctx_shared();
    let bg = [0.1, 0.5, 0.9];
    match kept {
        Some(k) => {
            let mut rec = Recorder::new(ctx).unwrap();
            rast.record_forward_kept(&mut rec, Splats::own(&set.params, 3), cam, &bg, frame, k).unwrap();
            rec.submit_and_wait().unwrap();
            assert!(rast.fit(frame).unwrap(), "a forward from a kept binning did not fit its frame");
            assert_eq!(frame.last_intersections, k.intersections(), "the intersection total read back is not the kept view's");
        }
        None => {
            rast.forward(&set.params, cam, &bg, 3, frame, false).unwrap();
        }
    }
    let mut out = vec![("image".to_string(), bits(&frame.out))];
    frame.grad_out.upload(grad_out).unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    if colour_only {
        rast.record_backward_colour(&mut rec, &set.params, &set.grads, 3, frame).unwrap();
    } else {
        rast.record_backward(&mut rec, &set.params, &set.grads, 3, frame).unwrap();
    }
    rec.submit_and_wait().unwrap();
    out.extend(set.grads.buffers().iter().zip(["means", "log_scales", "quats", "opacity", "features"]).map(|(b, n)| (format!("grad {n}"), bits(b))));
    out.push(("densify".to_string(), bits(&frame.densify)));
    out
}

/// Two views of 400 SH 3 Gaussians in a frame that starts with room for 16
/// intersections (so it grows between them): each view's binning is kept
/// after its first forward; then the colours change, and each view's
/// forward from its kept binning gives the full forward's image,
/// gradients (full and colour-only backward) and densification gradients
/// bit for bit. The first view's binning, kept before the frame grew,
/// still applies after.
#[test]
fn a_kept_binning_renders_and_differentiates_as_the_full_forward() {
    let ctx = ctx_shared();
    let FusedCase { host, cam, grad_out, .. } = fused_case("a_kept_binning_renders_and_differentiates_as_the_full_forward");
    let mut rng = Rng(seed("a_kept_binning_renders_and_differentiates_as_the_full_forward"));
    let cam_b = Camera::look_at([-1.2, 0.4, -3.5], [0.0, 0.1, 0.0], [0.0, -1.0, 0.1], 0.8, cam.width, cam.height);
    let rast = Rasterizer::new(ctx, 3, Features::Sh { degree: 3 }).unwrap();
    let set = TrainableSet::new(ctx, &host).unwrap();
    let mut frame = rast.frame(cam.width, cam.height, set.len(), 16).unwrap();
    let mut kept = Vec::new();
    for c in [&cam, &cam_b] {
        rast.forward(&set.params, c, &[0.1, 0.5, 0.9], 3, &mut frame, false).unwrap();
        assert!(frame.last_intersections > 0);
        let k = rast.keep_binning(&frame, set.len()).unwrap();
        assert_eq!(k.intersections(), frame.last_intersections);
        assert_eq!(k.bytes(), 4 * ((Rasterizer::kept_binning_bytes(&frame, set.len()) / 4).max(1)));
        kept.push(k);
    }
    assert!(frame.capacity > 16, "the frame did not grow");
    assert_ne!(kept[0].intersections(), kept[1].intersections());
    // New colours: the kept binning depends on the geometry alone.
    let features: Vec<f32> = host.features.iter().map(|f| f + 0.3 * (rng.uniform(-1.0, 1.0) as f32)).collect();
    set.params.features.upload(&features).unwrap();
    for colour_only in [false, true] {
        // Every full forward first: the frame then holds the other view's
        // binning when each kept one is used.
        let full: Vec<_> = [&cam, &cam_b].into_iter().map(|c| render_and_grads(&rast, &set, c, &mut frame, &grad_out, None, colour_only)).collect();
        for (v, (c, k)) in [&cam, &cam_b].into_iter().zip(&kept).enumerate() {
            let again = render_and_grads(&rast, &set, c, &mut frame, &grad_out, Some(k), colour_only);
            for ((name, a), (_, b)) in full[v].iter().zip(&again) {
                assert!(a == b, "view {v}: {name} differs between the full forward and the kept binning's (colour only: {colour_only})");
            }
            assert!(full[v][0].1.iter().any(|&x| f32::from_bits(x) != 0.0), "view {v} is empty");
        }
        assert!(full[0][0] != full[1][0], "the two views render the same image");
    }
    check_validation(ctx);
}

/// A kept binning is refused, by name, for a set of another size and for a
/// frame of another image size.
#[test]
fn a_kept_binning_of_other_gaussians_or_another_size_is_refused() {
    let ctx = ctx_shared();
    let FusedCase { host, cam, .. } = fused_case("a_kept_binning_of_other_gaussians_or_another_size_is_refused");
    let rast = Rasterizer::new(ctx, 3, Features::Sh { degree: 3 }).unwrap();
    let set = TrainableSet::new(ctx, &host).unwrap();
    let mut frame = rast.frame(cam.width, cam.height, set.len(), 4096).unwrap();
    rast.forward(&set.params, &cam, &[0.0; 3], 3, &mut frame, false).unwrap();
    let k = rast.keep_binning(&frame, set.len()).unwrap();
    let fewer = Gaussians::upload(ctx, &{
        let mut h = tgs_pipelines::HostGaussians::new(3, 16);
        for i in 0..10 {
            h.push([0.1 * i as f32, 0.0, 0.0], [-2.0, -2.0], [1.0, 0.0, 0.0, 0.0], 0.5, &[0.2; 48]);
        }
        h
    })
    .unwrap();
    let mut rec = Recorder::new(ctx).unwrap();
    let e = rast.record_forward_kept(&mut rec, Splats::own(&fewer, 3), &cam, &[0.0; 3], &frame, &k).unwrap_err();
    assert!(e.to_string().contains("kept binning is of 400 Gaussians; the set has 10"), "{e}");
    let small = Camera { width: cam.width / 2, height: cam.height / 2, ..cam };
    let other = rast.frame(small.width, small.height, set.len(), 4096).unwrap();
    let e = rast.record_forward_kept(&mut rec, Splats::own(&set.params, 3), &small, &[0.0; 3], &other, &k).unwrap_err();
    assert!(e.to_string().contains(&format!("kept binning is of a {}x{} view", cam.width, cam.height)), "{e}");
    drop(rec);
    check_validation(ctx);
}
