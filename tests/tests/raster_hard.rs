//! Hard cases of the 2DGS rasterizer: each must be free of NaN/Inf and agree
//! with the CPU f64 reference (see tests/src/raster_ref.rs for the
//! tolerances).

use tgs_pipelines::{Camera, Features, HostGaussians, Plane, RasterKernels, Rasterizer, RecordAccess};
use tgs_tests::raster_ref::{render, RefScene};
use tgs_tests::raster_util::*;
use tgs_tests::*;

/// Forward against the CPU, then a backward with random upstream gradients:
/// every gradient finite.
fn check_finite_backward(rast: &Rasterizer, scene: &HostGaussians, cam: &Camera, bg: &[f32], degree: u32, rng: &mut Rng, what: &str) -> GpuRun {
    check_forward(rast, scene, cam, bg, degree, what);
    let pixels = (cam.width * cam.height) as usize;
    let go = random_grads(rng, rast.channels(), pixels);
    let run = gpu_run(rast, scene, cam, bg, degree, Some(&go));
    let g = run.grads.as_ref().unwrap();
    for (name, v) in [("means", &g.means), ("log_scales", &g.log_scales), ("quats", &g.quats), ("opacity", &g.opacity), ("features", &g.features), ("densify", &run.densify)] {
        assert!(v.iter().all(|x| x.is_finite()), "{what}: non-finite {name} gradient");
    }
    run
}

#[test]
fn edge_on_splats() {
    let (ctx, rast, mut rng) = sh3_case("edge_on_splats");
    let cam = axis_camera(40, 30, 30.0);
    let mut s = HostGaussians::new(3, 16);
    for i in 0..40 {
        let m = [rng.uniform(-1.0, 1.0), rng.uniform(-0.8, 0.8), rng.uniform(2.5, 5.0)];
        let l = (m[0] * m[0] + m[1] * m[1] + m[2] * m[2]).sqrt();
        let d = [m[0] / l, m[1] / l, m[2] / l];
        // Normal perpendicular to the view ray through the centre.
        let r = [rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0)];
        let mut n = [d[1] * r[2] - d[2] * r[1], d[2] * r[0] - d[0] * r[2], d[0] * r[1] - d[1] * r[0]];
        let nl = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        n = n.map(|v| v / nl);
        // Every other splat is exactly edge-on (its plane passes through the
        // camera centre: invisible); the rest are tilted 0.1 to 3 degrees.
        if i % 2 == 1 {
            let t = [0.002, 0.01, 0.05][i / 2 % 3];
            n = [n[0] + t * d[0], n[1] + t * d[1], n[2] + t * d[2]];
            let l2 = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
            n = n.map(|v| v / l2);
        }
        let q = [1.0 + n[2], -n[1], n[0], 0.0].map(|v| v as f32);
        let ls = if i % 2 == 0 { [-1.5, -2.0] } else { [-2.5, -1.2] };
        s.push(m.map(|v| v as f32), ls, q, 1.0, &feats(&mut rng, 48));
    }
    // Exactly edge-on: centre on the optical axis, normal along x (culled).
    s.push([0.0, 0.0, 3.0], [-1.5, -1.5], [1.0, 0.0, 1.0, 0.0], 2.0, &feats(&mut rng, 48));
    let run = check_finite_backward(&rast, &s, &cam, &[0.2; 3], 3, &mut rng, "edge-on");
    assert!(run.out[3 * 1200..4 * 1200].iter().any(|&a| a > 0.1), "nearly edge-on splats should be visible");
    check_validation(ctx);
}

#[test]
fn tiny_and_huge_scales() {
    let (ctx, rast, mut rng) = sh3_case("tiny_and_huge_scales");
    let cam = axis_camera(37, 29, 30.0);
    let mut s = HostGaussians::new(3, 16);
    for i in 0..30 {
        let m = [rng.uniform(-0.8, 0.8), rng.uniform(-0.6, 0.6), rng.uniform(2.0, 5.0)].map(|v| v as f32);
        let ls = match i % 3 {
            0 => [(1e-6f32).ln(), (1e-6f32).ln()],
            1 => [(1e-6f32).ln(), -1.5],
            _ => [-2.0, -2.0],
        };
        s.push(m, ls, random_quat(&mut rng), rng.uniform(-1.0, 3.0) as f32, &feats(&mut rng, 48));
    }
    // Huge splats behind the others: one facing the camera, one tilted
    // (unbounded on screen: it covers every pixel). The first's opacity is
    // not 1/2, which would leave the second a transmittance of exactly 1/2
    // (the median depth's cut, a tie) at nearly every pixel.
    s.push([0.0, 0.0, 8.0], [(1e3f32).ln(), (1e3f32).ln()], [1.0, 0.0, 0.0, 0.0], 0.3, &feats(&mut rng, 48));
    s.push([0.3, 0.1, 9.0], [(1e3f32).ln(), 2.0], [0.9, 0.3, 0.2, 0.1], 0.5, &feats(&mut rng, 48));
    check_finite_backward(&rast, &s, &cam, &[0.2; 3], 3, &mut rng, "tiny and huge");
    check_validation(ctx);
}

#[test]
fn behind_camera_and_near_plane() {
    let (ctx, rast, mut rng) = sh3_case("behind_camera_and_near_plane");
    let cam = axis_camera(32, 24, 25.0);
    let mut s = HostGaussians::new(3, 16);
    let q = [1.0, 0.1, -0.1, 0.05];
    s.push([0.0, 0.0, -1.0], [-1.0, -1.0], q, 2.0, &feats(&mut rng, 48)); // behind
    s.push([0.01, 0.0, 0.1], [-1.0, -1.0], q, 2.0, &feats(&mut rng, 48)); // before the near plane
    s.push([0.0, 0.01, 0.2], [-1.0, -1.0], q, 2.0, &feats(&mut rng, 48)); // exactly at it (culled)
                                                                          // Straddling: centre just past the near plane, tilted and large, so
                                                                          // part of the splat is hit in front of z = 0.2 (those hits are skipped).
    s.push([0.0, 0.0, 0.25], [0.0, 0.0], [0.8, 0.5, 0.0, 0.0], 1.0, &feats(&mut rng, 48));
    s.push([0.05, -0.02, 0.21], [-0.5, -0.5], [0.9, 0.0, 0.4, 0.0], 1.0, &feats(&mut rng, 48));
    for _ in 0..10 {
        let m = [rng.uniform(-0.5, 0.5), rng.uniform(-0.4, 0.4), rng.uniform(1.5, 3.0)].map(|v| v as f32);
        s.push(m, [-2.0, -2.0], random_quat(&mut rng), 0.5, &feats(&mut rng, 48));
    }
    let run = check_finite_backward(&rast, &s, &cam, &[0.5; 3], 3, &mut rng, "behind/near");
    let g = run.grads.unwrap();
    for i in 0..3 {
        assert!(g.means[3 * i..3 * i + 3].iter().all(|&v| v == 0.0), "culled Gaussian {i} got a gradient");
    }
    check_validation(ctx);
}

#[test]
fn saturated_opacity_clamps_alpha() {
    let (ctx, rast, mut rng) = sh3_case("saturated_opacity_clamps_alpha");
    let cam = default_camera(36, 20);
    let mut spec = SceneSpec::new(12, 3, SH3);
    spec.log_scale = (-2.0, -1.0);
    // Raw opacity above 4.6 saturates (sigmoid > 0.99); up to 8 the opacity
    // gradients stay well above the finite differences' noise floor.
    spec.opacity = (2.0, 8.0);
    let mut scene = random_scene(&mut rng, &spec);
    // One splat facing the camera at the look-at point, about 6 px across
    // (G >= 0.99 at the nearest pixel centre): always saturates.
    scene.push([0.05, 0.02, 0.0], [0.0, 0.0], [1.0, 0.0, 0.0, 0.0], 30.0, &feats(&mut rng, 48));
    let run = check_finite_backward(&rast, &scene, &cam, &[0.0; 3], 3, &mut rng, "opacity -> 1");
    // Where the front splat saturates, alpha is 0.99 per layer: alpha output
    // reaches 1 - 0.01^k but never exceeds 1.
    let pixels = 36 * 20;
    let alpha = &run.out[3 * pixels..4 * pixels];
    assert!(alpha.iter().any(|&a| a > 0.98), "no saturated pixel");
    assert!(alpha.iter().all(|&a| (0.0..=1.0).contains(&a)));
    check_gradients(&rast, &scene, &cam, &[0.0; 3], 3, &mut rng, &[], "opacity -> 1");
    check_validation(ctx);
}

#[test]
fn equal_depths_keep_a_stable_order() {
    let ctx = ctx_shared();
    let rast = Rasterizer::new(ctx, 3, Features::Plain).unwrap();
    let mut rng = Rng(seed("equal_depths_keep_a_stable_order"));
    let cam = axis_camera(24, 20, 30.0);
    let colours = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]];
    let build = |order: &[usize]| {
        let mut s = HostGaussians::new(3, 1);
        for &i in order {
            let x = 0.05 * i as f32 - 0.07;
            s.push([x, 0.02 * i as f32, 3.0], [-1.6, -1.8], [1.0, 0.0, 0.0, 0.0], 1.0, &colours[i]);
        }
        s
    };
    let a = build(&[0, 1, 2, 3]);
    let b = build(&[3, 2, 1, 0]);
    let ra = check_forward(&rast, &a, &cam, &[0.0; 3], 0, "equal depths");
    let rb = check_forward(&rast, &b, &cam, &[0.0; 3], 0, "equal depths reversed");
    assert_ne!(ra.out, rb.out, "order of equal-depth splats had no effect: the test would not see a wrong order");
    // Moving any centre's depth changes the order: those 4 finite differences
    // straddle the discontinuity and are left out.
    check_gradients_with(&rast, &a, &cam, &[0.0; 3], 0, &mut rng, &[], 0.1, "equal depths");
    check_validation(ctx);
}

#[test]
fn empty_scene_and_one_pixel_image() {
    let (ctx, rast, mut rng) = sh3_case("empty_scene_and_one_pixel_image");
    let empty = HostGaussians::new(3, 16);
    let cam = default_camera(20, 10);
    let run = check_finite_backward(&rast, &empty, &cam, &[0.25, 0.5, 0.75], 3, &mut rng, "empty");
    let px = 200;
    for c in 0..3 {
        assert!(run.out[c * px..(c + 1) * px].iter().all(|&v| v == [0.25, 0.5, 0.75][c]));
    }
    assert!(run.out[3 * px..].iter().all(|&v| v == 0.0));
    assert_eq!(run.intersections, 0);

    let mut spec = SceneSpec::new(40, 3, SH3);
    spec.log_scale = (-1.5, -0.5);
    let one = default_camera(1, 1);
    // The gradient check needs the single pixel to be checkable (no severe
    // grazing hit on it, which happens in about one scene in eight).
    let scene = (0..20)
        .map(|_| random_scene(&mut rng, &spec))
        .find(|s| render(&RefScene::from_host(s, false), &one, &[0.1; 3], 3).gradient_checkable(0))
        .expect("no 1x1 scene with a checkable pixel in 20 draws");
    let r = check_finite_backward(&rast, &scene, &one, &[0.1; 3], 3, &mut rng, "1x1");
    assert!(r.out[3] > 0.0, "nothing covers the single pixel");
    check_gradients(&rast, &scene, &one, &[0.1; 3], 3, &mut rng, &[], "1x1");
    check_validation(ctx);
}

/// 50,000 splats in one tile: more loop iterations than lavapipe allows one
/// invocation, so the tile is cut into spans. Low opacities keep the
/// transmittance well above the 1e-4 stop so every splat is visited; they
/// are at least 0.006 so that each splat's opacity-aware box (low-pass disc
/// radius sqrt(ln(255 o)) >= 0.6 px about its centre) holds a pixel.
#[test]
fn tile_with_fifty_thousand_splats() {
    let ctx = ctx_shared();
    let rast = Rasterizer::new(ctx, 3, Features::Plain).unwrap();
    let mut rng = Rng(seed("tile_with_fifty_thousand_splats"));
    let cam = axis_camera(24, 20, 20.0);
    let mut s = HostGaussians::new(3, 1);
    // A few more than 50,000: a random orientation can be edge-on to within
    // rounding (culled, correctly), and the tile must keep 50,000.
    let n = 50_050;
    for _ in 0..n {
        let z = rng.uniform(2.0, 6.0);
        let (px, py) = (rng.uniform(3.0, 12.5), rng.uniform(3.0, 12.5));
        let m = [(px - cam.cx as f64) * z / 20.0, (py - cam.cy as f64) * z / 20.0, z];
        let o = rng.uniform(0.006, 0.009);
        s.push(m.map(|v| v as f32), [-7.0, -7.0], random_quat(&mut rng), (o / (1.0 - o)).ln() as f32, &feats(&mut rng, 3));
    }
    let run = check_forward_with(&rast, &s, &cam, &[0.0; 3], 0, 0.05, "50k splats in a tile");
    eprintln!("{} intersections in {} span passes of {}", run.intersections, run.spans, rast.span());
    assert!(run.intersections >= 50_000, "only {} splats in the tile", run.intersections);
    if ctx.caps().is_cpu() {
        assert!(run.spans > 1, "the heavy tile should need several spans on a CPU driver");
    }
    // Gradients of the front-most and back-most splats that reach a pixel,
    // against finite differences of the reference.
    let pixels = 24 * 20;
    let planes = Plane::count(3) as usize * pixels;
    let base = RefScene::from_host(&s, true);
    let reference = render(&base, &cam, &[0.0; 3], 0);
    // Zero weight where a discrete decision is ambiguous or a hit is
    // severely ill-conditioned (see raster_ref and check_gradients).
    let weights: Vec<f64> = (0..planes).map(|i| if reference.gradient_checkable(i % pixels) { rng.uniform(-1.0, 1.0) } else { 0.0 }).collect();
    let w32: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    let gpu = gpu_run(&rast, &s, &cam, &[0.0; 3], 0, Some(&w32));
    let g = gpu.grads.unwrap();
    let order = reference.splats;
    let reaches = |i: usize| {
        // Centre alpha above the cut: it contributes at its nearest pixel.
        let o = 1.0 / (1.0 + (-base.opacity[i]).exp());
        o > 1.0 / 255.0 * 1.01
    };
    let front = order.iter().find(|sp| reaches(sp.index)).unwrap().index;
    let back = order.iter().rev().find(|sp| reaches(sp.index)).unwrap().index;
    for (which, i) in [("front", front), ("back", back)] {
        let eps = 1e-6;
        let eval = |d: f64| {
            let mut sc = base.clone();
            sc.opacity[i] += d;
            ref_loss(&sc, &cam, &[0.0; 3], 0, &weights)
        };
        let fd = (eval(eps) - eval(-eps)) / (2.0 * eps);
        let gv = g.opacity[i] as f64;
        eprintln!("{which} splat {i}: opacity gradient gpu {gv:.6e} fd {fd:.6e}");
        assert!((gv - fd).abs() <= 1e-2 * fd.abs().max(1e-6), "{which} splat {i}: gpu {gv} vs fd {fd}");
    }
    check_validation(ctx);
}

/// More intersections than one storage binding can hold gradient records
/// for (128 MiB on lavapipe: 1.86M at 3 channels): the records are reached
/// by device address. 45,000 thin diagonal "filler" splats in front bin into
/// about 46 tiles each (16 x 16 tiles; 94 at 8 x 8) while reaching alpha
/// 1/255 at no pixel centre (a line between the centres, its low-pass disc
/// off screen: the tile culling keeps tiles within a pixel of the line), so
/// the 24 splats of a small scene behind them render and get gradients
/// exactly as alone, from record slots past the binding limit (they are
/// emitted last).
#[test]
fn gradient_records_past_the_binding_limit() {
    let ctx = ctx_shared();
    if !ctx.caps().buffer_device_address {
        eprintln!("no buffer device address on this device: skipped");
        return;
    }
    let rast = Rasterizer::with_records(ctx, 3, Features::Plain, None, RasterKernels::for_device(ctx.caps()), RecordAccess::Address).unwrap();
    let mut rng = Rng(seed("gradient_records_past_the_binding_limit"));
    let f = 256.0f32;
    let cam = axis_camera(256, 256, f);
    let mut small = HostGaussians::new(3, 1);
    for _ in 0..24 {
        let z = rng.uniform(8.0, 12.0);
        let (px, py) = (rng.uniform(40.0, 215.0), rng.uniform(40.0, 215.0));
        let m = [(px - cam.cx as f64) * z / f as f64, (py - cam.cy as f64) * z / f as f64, z];
        let ls = [0; 2].map(|_| rng.uniform(-2.5, -1.2) as f32);
        small.push(m.map(|v| v as f32), ls, random_quat(&mut rng), rng.uniform(-1.0, 2.0) as f32, &feats(&mut rng, 3));
    }
    let mut big = small.clone();
    let fillers = 45_000;
    // Long axis along screen (1, -1), centred at pixel (300, -44.5), off
    // screen: the line x + y = 255.5, 0.35 px from the nearest pixel centres,
    // across the whole image (o = 0.5: k = 3.11, half-length 435 px, half
    // width 0.16 px; the low-pass disc's radius is 2.2 px).
    let q = {
        let h = -std::f64::consts::FRAC_PI_8;
        [h.cos() as f32, 0.0, 0.0, h.sin() as f32]
    };
    for i in 0..fillers {
        let z = 4.0 + 2.0 * i as f64 / fillers as f64;
        let m = [(300.0 - cam.cx as f64) * z / f as f64, (-44.5 - cam.cy as f64) * z / f as f64, z];
        let ls = [(140.0 * z / f as f64).ln() as f32, (0.05 * z / f as f64).ln() as f32];
        big.push(m.map(|v| v as f32), ls, q, 0.0, &feats(&mut rng, 3));
    }
    let pixels = 256 * 256;
    let go = random_grads(&mut rng, 3, pixels);
    let alone = gpu_run(&rast, &small, &cam, &[0.2; 3], 0, Some(&go));
    let run = gpu_run(&rast, &big, &cam, &[0.2; 3], 0, Some(&go));
    let binding_cap = ctx.caps().max_storage_buffer_range / (4 * rast.record_len() as u64);
    eprintln!("{} intersections ({} alone); a binding holds records for {binding_cap}; {} span passes", run.intersections, alone.intersections, run.spans);
    assert!(run.intersections as u64 >= alone.intersections as u64 + 40 * fillers as u64, "fillers binned into {} tiles", run.intersections - alone.intersections);
    if ctx.caps().max_storage_buffer_range <= 128 << 20 {
        assert!(run.intersections as u64 > binding_cap);
        // The same scene with the records in a binding is refused by name.
        let by_binding = Rasterizer::with_records(ctx, 3, Features::Plain, None, RasterKernels::for_device(ctx.caps()), RecordAccess::Binding).unwrap();
        let g = tgs_pipelines::Gaussians::upload(ctx, &big).unwrap();
        let mut frame = by_binding.frame(256, 256, big.len() as u32, 1024).unwrap();
        let e = by_binding.forward(&g, &cam, &[0.2; 3], 0, &mut frame, false).unwrap_err();
        assert!(format!("{e:#}").contains("intersections; the device allows at most"), "{e:#}");
    }
    assert_eq!(bits(&run.out), bits(&alone.out), "the fillers changed the image");
    let (a, b) = (run.grads.as_ref().unwrap(), alone.grads.as_ref().unwrap());
    let n = small.len();
    for ((name, x), (_, y)) in named_arrays(a).into_iter().zip(named_arrays(b)) {
        let k = y.len() / n;
        assert!(y.iter().any(|v| *v != 0.0), "{name}: the small scene got no gradient");
        assert_eq!(bits(&x[..k * n]), bits(y), "{name}: gradients behind the fillers differ from the scene alone");
        assert!(x[k * n..].iter().all(|v| *v == 0.0), "{name}: a filler got a gradient");
    }
    check_validation(ctx);
}
