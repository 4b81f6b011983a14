//! The whole-iteration training benchmark runs on a small spheres scene and
//! reports a consistent breakdown (the timings themselves are for
//! `cargo bench`, never asserted).

use tgs_tests::{check_validation, ctx_shared};

#[test]
fn train_bench_reports_every_stage() {
    let ctx = ctx_shared();
    let b = tgs::bench_train::train(ctx, 32, 300, 0, 2).unwrap();
    assert_eq!((b.width, b.height, b.gaussians, b.views, b.iterations, b.warmup), (32, 32, 300, 20, 2, 3));
    assert!(b.intersections > 0);
    for (name, v) in [("wall", b.wall_ms), ("forward", b.forward_ms), ("loss", b.loss_ms), ("backward", b.backward_ms), ("adam", b.adam_ms)] {
        assert!(v.is_finite() && v >= 0.0, "{name}: {v}");
    }
    if ctx.caps().timestamp_valid_bits > 0 {
        assert!(b.forward_ms > 0.0 && b.backward_ms > 0.0 && b.adam_ms > 0.0);
        assert!((b.gpu_ms - (b.forward_ms + b.loss_ms + b.backward_ms + b.adam_ms)).abs() < 1e-9);
        for k in ["raster.forward", "raster.backward", "raster.reduce", "loss.ssim", "adam"] {
            assert!(b.kernels.iter().any(|t| t.name == k), "no timing for {k}");
        }
    }
    assert_eq!(b.brush_lavapipe_s, None);
    assert!(tgs::bench_train::train(ctx, 32, 300, 0, 0).is_err());
    check_validation(ctx);
}
