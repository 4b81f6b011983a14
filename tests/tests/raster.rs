//! The 2DGS rasterizer against the CPU f64 reference (forward) and central
//! finite differences of it (gradients), plus determinism, multi-span tiles
//! and the hard cases. CI runs this at subgroup 8 and 4.

use tgs_engine::Recorder;
use tgs_pipelines::{Features, Gaussians, RasterKernels, Rasterizer, RecordAccess};
use tgs_tests::raster_ref::RefScene;
use tgs_tests::raster_util::*;
use tgs_tests::*;

#[test]
fn forward_matches_cpu_random_scenes() {
    let (ctx, rast, mut rng) = sh3_case("forward_matches_cpu_random_scenes");
    for (w, h, n) in [(70, 45, 300), (16, 16, 50), (33, 17, 120)] {
        let scene = random_scene(&mut rng, &SceneSpec::new(n, 3, SH3));
        let cam = default_camera(w, h);
        check_forward(&rast, &scene, &cam, &[0.1, 0.5, 0.9], 3, &format!("{w}x{h} n={n}"));
    }
    check_validation(ctx);
}

/// Binning by the opacity-aware per-axis boxes drops no pixel a splat
/// reaches: the GPU render equals the reference in which every splat is
/// tested at every pixel of the image (no tiles), over opacities from below
/// 1/255 to 0.99 and anisotropic splats, at sizes that are not multiples of
/// the tile. And the boxes bin fewer tiles than 3-sigma squares (and the
/// splats are binned to no more tiles than their boxes' rectangles hold:
/// raster/tile_cull.glsl drops those they cannot reach).
#[test]
fn binning_drops_no_pixel_a_splat_reaches() {
    let (ctx, rast, mut rng) = sh3_case("binning_drops_no_pixel_a_splat_reaches");
    for (w, h, n) in [(70, 45, 300), (33, 17, 150), (100, 64, 400)] {
        let mut spec = SceneSpec::new(n, 3, SH3);
        spec.opacity = (-6.5, 4.6);
        spec.log_scale = (-4.0, -1.0);
        let scene = random_scene(&mut rng, &spec);
        let cam = default_camera(w, h);
        let run = gpu_run(&rast, &scene, &cam, &[0.1, 0.5, 0.9], 3, None);
        let ref_scene = RefScene::from_host(&scene, false);
        let tiles = [w.div_ceil(run.tile), h.div_ceil(run.tile)];
        let whole = vec![[0, 0, tiles[0], tiles[1]]; scene.len()];
        let cpu = raster_ref::render_with_rects(&ref_scene, &cam, &[0.1, 0.5, 0.9], 3, Some((&whole, run.tile)));
        let pixels = (w * h) as usize;
        let (err, at, skipped, _) = compare_forward(&run.out, &cpu, 3, pixels);
        assert!(err <= 1.0, "{w}x{h}: the binned render differs from the unbinned reference: {at}");
        assert!(skipped * 100 <= pixels, "{w}x{h}: {skipped} of {pixels} pixels ambiguous");
        let squares = raster_ref::square_box_tiles(&ref_scene, &cam, 3, run.tile);
        let faint = |g: usize| 1.0 / (1.0 + (-scene.opacity[g] as f64).exp()) < 1.0 / 255.0;
        let tiles_of = |r: &[u32; 4]| if r[2] > r[0] && r[3] > r[1] { ((r[2] - r[0]) * (r[3] - r[1])) as usize } else { 0 };
        let culled = (0..scene.len()).filter(|&g| faint(g)).count();
        let binned: usize = run.rects.iter().map(tiles_of).sum();
        eprintln!("{w}x{h}: {} intersections (3-sigma squares: {squares}); {culled} of {n} splats below alpha 1/255", run.intersections);
        assert!(run.intersections as usize <= binned, "{w}x{h}: {} intersections, more than the rectangles' {binned} tiles", run.intersections);
        assert!(culled > 0 && (0..scene.len()).all(|g| !faint(g) || tiles_of(&run.rects[g]) == 0));
        assert!(run.intersections as usize * 10 < squares * 9, "{w}x{h}: {} intersections, 3-sigma squares {squares}", run.intersections);
    }
    check_validation(ctx);
}

/// The gradient records reached through a binding or by device address
/// give bit-identical images and gradients (same kernels otherwise).
#[test]
fn records_by_binding_and_by_address_agree() {
    let ctx = ctx_shared();
    if !ctx.caps().buffer_device_address {
        eprintln!("no buffer device address on this device: skipped");
        return;
    }
    let mut rng = Rng(seed("records_by_binding_and_by_address_agree"));
    let scene = random_scene(&mut rng, &SceneSpec::new(300, 3, SH3));
    let cam = default_camera(70, 45);
    let go = random_grads(&mut rng, 3, 70 * 45);
    for kernels in [RasterKernels::Subgroup, RasterKernels::Workgroup] {
        let runs: Vec<_> = [RecordAccess::Binding, RecordAccess::Address]
            .map(|records| {
                let rast = Rasterizer::with_records(ctx, 3, SH3, None, kernels, records).unwrap();
                assert_eq!(rast.records(), records);
                gpu_run(&rast, &scene, &cam, &[0.1, 0.5, 0.9], 3, Some(&go))
            })
            .into_iter()
            .collect();
        assert_eq!(bits(&runs[0].out), bits(&runs[1].out), "{kernels:?}: images differ");
        let (a, b) = (runs[0].grads.as_ref().unwrap(), runs[1].grads.as_ref().unwrap());
        assert!(a.means.iter().any(|v| *v != 0.0));
        for ((name, x), (_, y)) in named_arrays(a).into_iter().zip(named_arrays(b)) {
            assert_eq!(bits(x), bits(y), "{kernels:?}: {name} gradients differ");
        }
        assert_eq!(bits(&runs[0].densify), bits(&runs[1].densify));
    }
    check_validation(ctx);
}

#[test]
fn gradients_match_finite_differences_sh3() {
    let (ctx, rast, mut rng) = sh3_case("gradients_match_finite_differences_sh3");
    let mut spec = SceneSpec::new(12, 3, SH3);
    spec.log_scale = (-2.2, -1.0);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(40, 24);
    check_gradients(&rast, &scene, &cam, &[0.2, 0.3, 0.7], 3, &mut rng, &[], "sh3");
    check_validation(ctx);
}

#[test]
fn gradients_plain_features_one_and_eight_channels() {
    plain_features(Rng(seed("gradients_plain_features_one_and_eight_channels")));
}

/// The seed that found a gap in the reference's ambiguity test: at pixel
/// 84 of the eight-channel scene a splat seen at a grazing angle has alpha
/// 1.1e-6 below the 1/255 cut, within its f32 sensitivity (8.9e-6), and the
/// GPU kept it (median depth 3.54 against none). The reference now leaves
/// such pixels out; this keeps that case.
#[test]
fn alpha_cut_within_rounding_of_a_grazing_hit() {
    plain_features(Rng(1795566249080618654));
}

fn plain_features(mut rng: Rng) {
    let ctx = ctx_shared();
    for ch in [1u32, 8] {
        let rast = Rasterizer::new(ctx, ch, Features::Plain).unwrap();
        let mut spec = SceneSpec::new(10, ch, Features::Plain);
        spec.log_scale = (-2.2, -1.0);
        let scene = random_scene(&mut rng, &spec);
        let cam = default_camera(35, 21);
        let bg: Vec<f32> = (0..ch).map(|c| 0.1 * c as f32).collect();
        check_forward(&rast, &scene, &cam, &bg, 0, &format!("plain C={ch}"));
        check_gradients(&rast, &scene, &cam, &bg, 0, &mut rng, &[], &format!("plain C={ch}"));
    }
    check_validation(ctx);
}

#[test]
fn sh_degree_zero_and_partial_activation() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("sh_degree_zero_and_partial_activation"));
    // Degree-0 SH (one coefficient per channel).
    let f0 = Features::Sh { degree: 0 };
    let rast = Rasterizer::new(ctx, 3, f0).unwrap();
    let mut spec = SceneSpec::new(10, 3, f0);
    spec.log_scale = (-2.2, -1.0);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(30, 20);
    check_forward(&rast, &scene, &cam, &[0.0; 3], 0, "sh0");
    check_gradients(&rast, &scene, &cam, &[0.0; 3], 0, &mut rng, &[], "sh0");
    // Degree-3 storage with degree 1 active: higher coefficients have no effect
    // (their gradient is exactly zero) and the forward ignores them.
    let rast = Rasterizer::new(ctx, 3, SH3).unwrap();
    let mut spec = SceneSpec::new(10, 3, SH3);
    spec.log_scale = (-2.2, -1.0);
    let scene = random_scene(&mut rng, &spec);
    check_forward(&rast, &scene, &cam, &[0.0; 3], 1, "sh3 active 1");
    check_gradients(&rast, &scene, &cam, &[0.0; 3], 1, &mut rng, &[], "sh3 active 1");
    let pixels = 30 * 20;
    let run = gpu_run(&rast, &scene, &cam, &[0.0; 3], 1, Some(&constant_grads(3, pixels, 1.0)));
    let g = run.grads.unwrap();
    for i in 0..scene.len() {
        for k in 4..16 {
            for c in 0..3 {
                assert_eq!(g.features[(i * 16 + k) * 3 + c], 0.0, "inactive SH coefficient {k} got a gradient");
            }
        }
    }
    check_validation(ctx);
}

#[test]
fn backward_is_bit_identical_run_to_run() {
    let (ctx, rast, mut rng) = sh3_case("backward_is_bit_identical_run_to_run");
    let mut spec = SceneSpec::new(2000, 3, SH3);
    spec.log_scale = (-3.0, -1.5);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(64, 48);
    let pixels = 64 * 48;
    let grads = random_grads(&mut rng, 3, pixels);
    let a = gpu_run(&rast, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    let b = gpu_run(&rast, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    assert!(a.intersections > 2000, "scene too sparse: {} intersections", a.intersections);
    assert_eq!(bits(&a.out), bits(&b.out), "forward differs between runs");
    let (ga, gb) = (a.grads.unwrap(), b.grads.unwrap());
    for (name, x, y) in [
        ("means", &ga.means, &gb.means),
        ("log_scales", &ga.log_scales, &gb.log_scales),
        ("quats", &ga.quats, &gb.quats),
        ("opacity", &ga.opacity, &gb.opacity),
        ("features", &ga.features, &gb.features),
        ("densify", &a.densify, &b.densify),
    ] {
        assert_eq!(bits(x), bits(y), "{name} gradients differ between runs");
        assert!(x.iter().any(|&v| v != 0.0), "{name} gradients are all zero");
    }
    check_validation(ctx);
}

/// Tiles longer than the span take several passes; with a forced span of
/// half the default a dense scene must give bit-identical outputs and
/// gradients to the run with the device's default span (the per-pixel
/// operation sequence is the same however the list is cut).
#[test]
fn multi_span_tiles_match_single_span() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("multi_span_tiles_match_single_span"));
    let mut spec = SceneSpec::new(3000, 3, SH3);
    spec.log_scale = (-2.5, -1.5);
    spec.opacity = (-6.0, -3.0);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(40, 24);
    let pixels = 40 * 24;
    let grads = random_grads(&mut rng, 3, pixels);
    let one = Rasterizer::new(ctx, 3, SH3).unwrap();
    let short = (one.span().min(512) / 2).max(32) / 32 * 32;
    let many = Rasterizer::with_span(ctx, 3, SH3, Some(short)).unwrap();
    let a = gpu_run(&one, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    let b = gpu_run(&many, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    assert!(b.spans >= 4 && b.spans > a.spans, "expected more spans with the short span: {} vs {}", b.spans, a.spans);
    eprintln!("{} intersections, {} spans of {short} (default span {}: {})", b.intersections, b.spans, one.span(), a.spans);
    assert_eq!(bits(&a.out), bits(&b.out), "forward differs");
    let (ga, gb) = (a.grads.unwrap(), b.grads.unwrap());
    assert_eq!(bits(&ga.means), bits(&gb.means));
    assert_eq!(bits(&ga.quats), bits(&gb.quats));
    assert_eq!(bits(&ga.features), bits(&gb.features));
    assert_eq!(bits(&ga.opacity), bits(&gb.opacity));
    // A dense pile of faint splats: more pixels sit at the 1/255 cut (the
    // same allowance as the 50k-splat pile).
    check_forward_with(&many, &scene, &cam, &[0.3; 3], 3, 0.05, "short span");
    check_validation(ctx);
}

/// Both tile-kernel variants on this device: the Workgroup kernels (what
/// GPUs run) against the f64 reference and finite differences, as the
/// default kernels are above; the two forwards bit-identical (the same
/// per-pixel operations); the two backwards equal up to the order their
/// per-splat sums are added in, each bit-identical run to run.
#[test]
fn workgroup_and_subgroup_kernels_agree() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("workgroup_and_subgroup_kernels_agree"));
    let wg = Rasterizer::with_options(ctx, 3, SH3, None, RasterKernels::Workgroup).unwrap();
    let sg = Rasterizer::with_options(ctx, 3, SH3, None, RasterKernels::Subgroup).unwrap();
    assert_eq!((wg.kernels(), sg.kernels()), (RasterKernels::Workgroup, RasterKernels::Subgroup));
    let mut spec = SceneSpec::new(12, 3, SH3);
    spec.log_scale = (-2.2, -1.0);
    let small = random_scene(&mut rng, &spec);
    let cam = default_camera(40, 24);
    check_forward(&wg, &small, &cam, &[0.1, 0.5, 0.9], 3, "workgroup kernels");
    check_gradients(&wg, &small, &cam, &[0.2, 0.3, 0.7], 3, &mut rng, &[], "workgroup kernels");

    let mut spec = SceneSpec::new(2000, 3, SH3);
    spec.opacity = (-4.0, 2.0);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(70, 45);
    let grads = random_grads(&mut rng, 3, 70 * 45);
    let a = gpu_run(&wg, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    let b = gpu_run(&sg, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    let b2 = gpu_run(&sg, &scene, &cam, &[0.3; 3], 3, Some(&grads));
    assert_eq!(bits(&a.out), bits(&b.out), "the two forwards differ");
    let (ga, gb, gb2) = (a.grads.unwrap(), b.grads.unwrap(), b2.grads.unwrap());
    for (name, x, y, y2) in [
        ("means", &ga.means, &gb.means, &gb2.means),
        ("log_scales", &ga.log_scales, &gb.log_scales, &gb2.log_scales),
        ("quats", &ga.quats, &gb.quats, &gb2.quats),
        ("opacity", &ga.opacity, &gb.opacity, &gb2.opacity),
        ("features", &ga.features, &gb.features, &gb2.features),
    ] {
        assert_eq!(bits(y), bits(y2), "{name}: subgroup backward not bit-identical run to run");
        // A few sums are ill-conditioned in f32 (large per-pixel terms that
        // nearly cancel, e.g. a splat seen almost edge-on): any change of
        // summation order moves them, as it moves the FD check's excluded
        // pixels. Measured over 25 seeds: scales have 3-13 of 4,000 elements
        // beyond 1e-4 relative and 0-7 beyond 1e-3, every other group none;
        // a wrong kernel differs almost everywhere.
        let rms = (x.iter().map(|&t| (t as f64).powi(2)).sum::<f64>() / x.len().max(1) as f64).sqrt();
        let beyond = |tol: f64| (0..x.len()).filter(|&i| ((x[i] - y[i]).abs() as f64) > tol * (x[i].abs() + y[i].abs()) as f64 + 1e-6 * rms).collect::<Vec<_>>();
        let (loose, tight) = (beyond(1e-3), beyond(1e-4));
        eprintln!("{name}: of {} elements, {} differ by more than 1e-4 relative, {} by more than 1e-3", x.len(), tight.len(), loose.len());
        for &i in loose.iter().take(3) {
            eprintln!("   [{i}] workgroup {} subgroup {} (rms {rms:.3e})", x[i], y[i]);
        }
        assert!(rms > 0.0, "{name}: all zero");
        assert!(
            loose.len() * 100 <= x.len() && tight.len() * 50 <= x.len(),
            "{name}: {} (1e-3) and {} (1e-4) of {} elements differ between the two backwards",
            loose.len(),
            tight.len(),
            x.len()
        );
    }
    check_validation(ctx);
}

/// The feature-only backward (a set whose geometry does not train: Stage
/// III's scattering colour) gives feature gradients bit-identical to the
/// full backward's, with both tile kernels and both record accesses, on a
/// scene whose tiles take several spans; and its geometry records are
/// zero, so the positions get only the colour's view-direction term.
#[test]
fn colour_only_backward_matches_the_full_feature_gradients() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("colour_only_backward_matches_the_full_feature_gradients"));
    let mut spec = SceneSpec::new(1500, 3, SH3);
    spec.log_scale = (-2.5, -1.2);
    spec.opacity = (-5.0, 2.0);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(40, 24);
    let go = random_grads(&mut rng, 3, 40 * 24);
    let g = tgs_pipelines::Gaussians::upload(ctx, &scene).unwrap();
    let accesses: &[RecordAccess] = if ctx.caps().buffer_device_address { &[RecordAccess::Binding, RecordAccess::Address] } else { &[RecordAccess::Binding] };
    for kernels in [RasterKernels::Subgroup, RasterKernels::Workgroup] {
        for &records in accesses {
            let one = Rasterizer::with_records(ctx, 3, SH3, None, kernels, records).unwrap();
            let short = (one.span().min(512) / 2).max(32) / 32 * 32;
            let rast = Rasterizer::with_records(ctx, 3, SH3, Some(short), kernels, records).unwrap();
            let mut frame = rast.frame(cam.width, cam.height, scene.len() as u32, 1024).unwrap();
            rast.forward(&g, &cam, &[0.3; 3], 3, &mut frame, false).unwrap();
            frame.grad_out.upload(&go).unwrap();
            let full = tgs_pipelines::Gaussians::zeros(ctx, g.n, g.channels, g.coeffs).unwrap();
            rast.backward(&g, &full, 3, &frame, false).unwrap();
            let colour = tgs_pipelines::Gaussians::zeros(ctx, g.n, g.channels, g.coeffs).unwrap();
            let mut rec = tgs_engine::Recorder::new(ctx).unwrap();
            rast.record_backward_colour(&mut rec, &g, &colour, 3, &frame).unwrap();
            rec.submit_and_wait().unwrap();
            let (full, colour) = (full.download().unwrap(), colour.download().unwrap());
            assert!(frame.spans >= 2, "{kernels:?}: the scene should take several spans, not {}", frame.spans);
            assert!(full.features.iter().filter(|v| **v != 0.0).count() > full.features.len() / 4, "{kernels:?}: too few feature gradients");
            assert_eq!(bits(&full.features), bits(&colour.features), "{kernels:?} {records:?}: feature gradients differ");
            for (name, v) in [("log_scales", &colour.log_scales), ("quats", &colour.quats), ("opacity", &colour.opacity)] {
                assert!(v.iter().all(|x| *x == 0.0), "{kernels:?}: {name} gradients should be zero without geometric records");
            }
            let moved = |v: &[f32], w: &[f32]| v.iter().zip(w).filter(|(a, b)| a != b).count();
            assert!(moved(&full.means, &colour.means) > full.means.len() / 4, "{kernels:?}: the positions' gradients should lack the geometric terms");
        }
    }
    check_validation(ctx);
}

/// The colour-only forward (a final image: `tgs::embed`, the viewer) gives
/// the full forward's feature and alpha planes bit for bit — an ordinary
/// scene with both tile kernels, both tile sizes and tiles over several
/// span passes — and writes no other plane.
#[test]
fn a_colour_only_forward_gives_the_full_forwards_colour() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("a_colour_only_forward_gives_the_full_forwards_colour"));
    let cam = default_camera(45, 38);
    let mut spec = SceneSpec::new(400, 3, SH3);
    spec.log_scale = (-3.0, -1.0);
    let scene = random_scene(&mut rng, &spec);
    let bg = [0.3, 0.6, 0.1];
    const SENTINEL: f32 = -3.5;
    let planes = (cam.width * cam.height) as usize;
    for (kernels, small, span) in
        [(RasterKernels::Subgroup, true, None), (RasterKernels::Subgroup, false, Some(32)), (RasterKernels::Workgroup, false, None), (RasterKernels::Workgroup, false, Some(32))]
    {
        let what = format!("{kernels:?}, small tiles {small}, span {span:?}");
        let rast = Rasterizer::with_options(ctx, 3, SH3, span, kernels).unwrap().small_tiles(small);
        let full = gpu_run(&rast, &scene, &cam, &bg, 3, None);
        let g = Gaussians::upload(ctx, &scene).unwrap();
        let mut frame = rast.frame(cam.width, cam.height, scene.len() as u32, 64).unwrap();
        frame.out.upload(&vec![SENTINEL; frame.out.len()]).unwrap();
        for tries in 0.. {
            assert!(tries < 4, "{what}: the view never fitted its frame");
            let mut rec = Recorder::new(ctx).unwrap();
            rast.record_forward_colour(&mut rec, &g, &cam, &bg, 3, &frame).unwrap();
            rec.submit_and_wait().unwrap();
            if rast.fit(&mut frame).unwrap() {
                break;
            }
        }
        assert!(span.is_none() || frame.spans > 1, "{what}: one span pass");
        let out = frame.out.download().unwrap();
        let colour = 4 * planes; // three features and alpha
        assert_eq!(bits(&out[..colour]), bits(&full.out[..colour]), "{what}: colour or alpha differs from the full forward's");
        assert!(out[colour..].iter().all(|&v| v == SENTINEL), "{what}: wrote a plane past alpha");
    }
    check_validation(ctx);
}
