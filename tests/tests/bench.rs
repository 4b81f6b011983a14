//! The whole-iteration training benchmark runs on a small spheres scene and
//! reports a consistent breakdown (the timings themselves are for
//! `cargo bench`, never asserted).

use tgs_tests::{check_validation, ctx_shared};

#[test]
fn train_bench_reports_every_stage() {
    let ctx = ctx_shared();
    for fuse in [true, false] {
        let b = tgs::bench_train::train(ctx, tgs::bench_train::Workload::square(32, 300), 0, 2, Some(fuse)).unwrap();
        assert_eq!((b.width, b.height, b.gaussians, b.views, b.iterations, b.warmup), (32, 32, 300, 20, 2, 3));
        assert!(b.intersections > 0);
        let can = tgs_pipelines::Rasterizer::new(ctx, 3, tgs_pipelines::Features::Sh { degree: 3 }).unwrap().can_fuse_adam();
        assert_eq!(b.adam_fused, fuse && can);
        // Keys, values, ids, two sort arrays and the 18-float record.
        assert_eq!(b.bytes_per_intersection, 4 * (5 + 18));
        assert!(b.peak_memory_mib > 0.0 && b.peak_memory_mib.is_finite());
        for (name, v) in [("wall", b.wall_ms), ("forward", b.forward_ms), ("loss", b.loss_ms), ("backward", b.backward_ms), ("adam", b.adam_ms)] {
            assert!(v.is_finite() && v >= 0.0, "{name}: {v}");
        }
        if ctx.caps().timestamp_valid_bits > 0 {
            assert!(b.forward_ms > 0.0 && b.backward_ms > 0.0 && b.adam_ms > 0.0);
            assert!((b.gpu_ms - (b.forward_ms + b.loss_ms + b.backward_ms + b.adam_ms)).abs() < 1e-9);
            let mut scopes = vec!["raster.forward", "raster.backward", "raster.reduce", "loss.ssim"];
            if !b.adam_fused {
                scopes.push("adam");
            }
            for k in scopes {
                assert!(b.kernels.iter().any(|t| t.name == k), "no timing for {k}");
            }
            assert_eq!(b.kernels.iter().any(|t| t.name == "adam"), !b.adam_fused, "an Adam pass of its own only when not fused");
        }
        assert_eq!(b.brush_lavapipe_s, None);
    }
    assert!(tgs::bench_train::train(ctx, tgs::bench_train::Workload::square(32, 300), 0, 0, None).is_err());
    // A frame that is not square (the real-scale workload's shape, small).
    let w = tgs::bench_train::Workload { width: 40, height: 24, points: 200, views: 2 };
    let b = tgs::bench_train::train(ctx, w, 0, 1, None).unwrap();
    // Training's own choice: fused on CPU devices only.
    assert_eq!(b.adam_fused, ctx.caps().is_cpu() && tgs_pipelines::Rasterizer::new(ctx, 3, tgs_pipelines::Features::Sh { degree: 3 }).unwrap().can_fuse_adam());
    assert_eq!((b.width, b.height, b.gaussians, b.views), (40, 24, 200, 2));
    assert!(b.intersections > 0 && b.wall_ms.is_finite());
    // Sizes whose images cannot fit are refused before anything is rendered.
    for w in [tgs::bench_train::Workload { width: 20_000, height: 8, points: 10, views: 1 }, tgs::bench_train::Workload { width: 16_000, height: 16_000, points: 10, views: 20 }] {
        let e = format!("{:#}", tgs::bench_train::train(ctx, w, 0, 1, None).unwrap_err());
        assert!(e.contains("host memory"), "{e}");
    }
    assert!(tgs::bench_train::train(ctx, tgs::bench_train::Workload { views: 0, ..tgs::bench_train::Workload::square(32, 300) }, 0, 1, None).is_err());
    check_validation(ctx);
}

/// `tgs bench train --from RUN` on a 12-iteration Stage I run of the tiny
/// glass scene: the run's own Gaussians and frame, the count fixed, the run
/// directory untouched; a directory without a checkpoint is refused by name.
#[test]
fn train_bench_from_a_trained_run() {
    let ctx = ctx_shared();
    let base = tgs_tests::TempDir::created("bench-train-from");
    let ds = tgs_tests::tiny_glass_scene(&std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("bench-from-scene"));
    let run = base.join("run");
    let set = ["stages=\"I\"", "background=\"black\"", "test_interval=0", "checkpoint_interval=0", "densify_from=1000"];
    let args = tgs::train::run::TrainArgs {
        dataset: Some(ds),
        out: run.clone(),
        iterations: Some(12),
        set: set.iter().map(|s| s.to_string()).collect(),
        quiet: true,
        ..Default::default()
    };
    tgs::train::run::train(ctx, &args).unwrap();
    let ckpt = run.join("checkpoint.bin");
    let before = std::fs::read(&ckpt).unwrap();
    let (h, _) = tgs::train::checkpoint::read(&ckpt).unwrap();
    let files = std::fs::read_dir(&run).unwrap().count();
    let b = tgs::bench_train::train_from(ctx, &run, 1, 2, None).unwrap();
    assert_eq!((b.gaussians, b.iterations, b.warmup), (h.n, 2, 1));
    assert_eq!((b.width, b.height, b.views), (48, 48, 16));
    assert!(b.intersections > 0 && b.wall_ms.is_finite() && b.wall_ms_best <= b.wall_ms);
    if ctx.caps().timestamp_valid_bits > 0 {
        assert!(b.forward_ms > 0.0 && b.backward_ms > 0.0);
    }
    assert_eq!(std::fs::read(&ckpt).unwrap(), before, "the bench wrote over the run's checkpoint");
    assert_eq!(std::fs::read_dir(&run).unwrap().count(), files, "the bench wrote into the run directory");
    let empty = base.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let e = format!("{:#}", tgs::bench_train::train_from(ctx, &empty, 0, 1, None).unwrap_err());
    assert!(e.contains("checkpoint.bin") && e.contains(&*empty.to_string_lossy()), "{e}");
    assert!(tgs::bench_train::train_from(ctx, &run, 0, 0, None).is_err());
    // `tgs bench view` on the same run: its frame at another size, the
    // stage and counts of its checkpoint; nothing written into the run.
    let v = tgs::bench_view::view(ctx, &run, (20, 14), 3, false).unwrap();
    assert_eq!((v.stage.as_str(), v.gaussians, v.width, v.height, v.frames), ("I", (h.n as usize, 0), 20, 14, 3));
    assert!(v.mean_ms.is_finite() && v.mean_ms > 0.0 && v.best_ms <= v.mean_ms && v.fps > 0.0);
    assert!(v.scopes.is_empty(), "scopes without --profile: {:?}", v.scopes);
    // With --profile: the frame's scope and the scattering set's inside it.
    let p = tgs::bench_view::view(ctx, &run, (20, 14), 2, true).unwrap();
    if ctx.caps().timestamp_valid_bits > 0 {
        let ms = |n: &str| p.scopes.iter().find(|s| s.0 == n).map(|s| s.1).unwrap_or_else(|| panic!("no scope {n}: {:?}", p.scopes));
        assert!(ms("view.frame") > 0.0 && ms("view.scattering") <= ms("view.frame"), "{:?}", p.scopes);
    }
    assert_eq!(std::fs::read_dir(&run).unwrap().count(), files, "the view bench wrote into the run directory");
    let e = format!("{:#}", tgs::bench_view::view(ctx, &empty, (20, 14), 3, false).unwrap_err());
    assert!(e.contains("checkpoint.bin"), "{e}");
    assert!(tgs::bench_view::view(ctx, &run, (0, 14), 3, false).is_err() && tgs::bench_view::view(ctx, &run, (20, 14), 0, false).is_err());
    check_validation(ctx);
}

/// `tgs bench stages` on the tiny glass scene: every stage runs, each
/// reports its own kernels, the Gaussian counts stay fixed while timing,
/// the memory counters move, and Stage III reports the fraction Φ ran on.
#[test]
fn stages_bench_reports_each_stage() {
    let ctx = ctx_shared();
    let spec = tgs::bench_stages::StagesSpec { scene: "glass-tiny".into(), train: 8, train_light_field: 4, warmup: 1, iterations: 2, mlp: "small".into(), set: vec![] };
    let b = tgs::bench_stages::stages(ctx, &spec).unwrap();
    assert_eq!((b.width, b.height, b.train_views), (48, 48, 16));
    let names: Vec<&str> = b.stages.iter().map(|s| s.stage.as_str()).collect();
    assert_eq!(names, ["I", "II", "III"], "skipped: {:?}", b.skipped);
    let own = [("I", "raster.backward", "refl.color"), ("II", "refl.color_backward", "mlp.forward"), ("III", "mlp.backward", "refl.color")];
    for (s, (stage, has, lacks)) in b.stages.iter().zip(own) {
        assert!(s.wall_ms.is_finite() && s.wall_ms > 0.0 && s.wall_ms_best <= s.wall_ms, "{stage}: {s:?}");
        assert!(s.memory_mib > 0.0 && s.peak_memory_mib >= s.memory_mib, "{stage}: {s:?}");
        assert_eq!(s.switch_ms.is_some(), stage != "I");
        assert_eq!(s.reflection_gaussians.is_some(), stage != "I");
        assert_eq!(s.phi_fraction.is_some(), stage == "III");
        if ctx.caps().timestamp_valid_bits > 0 {
            assert!(s.kernels.iter().any(|k| k.name == has), "Stage {stage} has no {has}: {:?}", s.kernels);
            assert!(!s.kernels.iter().any(|k| k.name == lacks), "Stage {stage} runs {lacks}");
            let top: f64 = s.kernels.iter().filter(|k| !k.name.starts_with("sort.") && !k.name.starts_with("scan.")).map(|k| k.ms).sum();
            assert!((s.gpu_ms - top).abs() < 1e-9 && s.gpu_ms > 0.0);
        }
    }
    let f = b.stages[2].phi_fraction.unwrap();
    assert!((0.0..=1.0).contains(&f), "{f}");
    // Stage II's set carries over to Stage III unchanged (geometry frozen, no pruning).
    assert_eq!(b.stages[1].reflection_gaussians, b.stages[2].reflection_gaussians);
    assert!(tgs::bench_stages::stages(ctx, &tgs::bench_stages::StagesSpec { iterations: 0, ..spec.clone() }).is_err());
    assert!(tgs::bench_stages::stages(ctx, &tgs::bench_stages::StagesSpec { scene: "nope".into(), ..spec.clone() }).is_err());
    // --set: the residual's seeds instead of the scene's training masks
    // cover more of the image, so Φ runs on more of it; the settings are
    // recorded. A key the bench sets itself, or an unknown one, is refused
    // by name.
    let residual = tgs::bench_stages::StagesSpec { set: vec!["reflection.dataset_masks=false".into()], ..spec.clone() };
    let r = tgs::bench_stages::stages(ctx, &residual).unwrap();
    assert_eq!(r.set, residual.set);
    assert!(b.set.is_empty());
    let (masked, unmasked) = (f, r.stages[2].phi_fraction.unwrap());
    assert!(unmasked > masked, "Φ on {unmasked} of the pixels from the residual's seeds, {masked} from the masks'");
    for bad in ["iterations=5", "reflection.iterations=3", "no_such_key=1"] {
        let e = tgs::bench_stages::stages(ctx, &tgs::bench_stages::StagesSpec { set: vec![bad.into()], ..spec.clone() }).unwrap_err();
        let key = bad.split('=').next().unwrap();
        assert!(format!("{e:#}").contains(key), "{bad}: {e:#}");
    }
    check_validation(ctx);
}

/// `tgs bench train --light-field`: Stage III iterations on the spheres
/// (the scattering colour and a reflection set of every tenth Gaussian
/// under the small light field) report the sizes they ran, Φ's share of the
/// pixels, the MLP's scopes and the colour's from kept weights (after a
/// warm-up that renders every view in full once, nothing walks a tile or
/// sorts), and the peak memory.
#[test]
fn light_field_bench_times_stage_three() {
    let ctx = ctx_shared();
    let w = tgs::bench_train::Workload { width: 40, height: 24, points: 300, views: 2 };
    let b = tgs::bench_light_field::light_field(ctx, w, 0, 2, tgs::train::stages::light_field::settings::LightPreset::Small).unwrap();
    assert_eq!((b.width, b.height, b.scattering_gaussians, b.reflection_gaussians, b.iterations), (40, 24, 300, 30, 2));
    assert_eq!(b.network, "small");
    assert!(b.wall_ms.is_finite() && b.wall_ms > 0.0 && b.wall_ms_best <= b.wall_ms);
    assert!(b.phi_fraction.is_some_and(|f| (0.0..=1.0).contains(&f)), "{:?}", b.phi_fraction);
    assert_eq!(b.mlp_block, 40 * 24, "one block holds a small frame's samples");
    assert!(b.peak_memory_mib > 0.0 && b.peak_memory_mib.is_finite());
    if ctx.caps().timestamp_valid_bits > 0 {
        for k in ["raster.kept_colour", "raster.kept_grad", "raster.reduce", "mlp.forward", "mlp.backward", "lf.composite"] {
            assert!(b.kernels.iter().any(|t| t.name == k), "no timing for {k}");
        }
        // The warm-up rendered every view in full once; the timed
        // iterations sort nothing and walk no tile.
        for k in ["raster.depth_sort", "raster.forward", "raster.backward"] {
            assert!(!b.kernels.iter().any(|t| t.name == k), "{k} in {:?}", b.kernels);
        }
        assert!(b.gpu_ms > 0.0);
    }
    assert_eq!(b.warmup, 2, "the warm-up visits every view");
    assert!(tgs::bench_light_field::light_field(ctx, w, 0, 0, tgs::train::stages::light_field::settings::LightPreset::Small).is_err(), "no timed iterations must be refused");
    check_validation(ctx);
}
