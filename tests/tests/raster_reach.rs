//! Where splats reach on screen: the pixel boxes and the tiles a splat is
//! binned to hold every pixel the f64 reference sees it reach, on a scene
//! of tiny, huge, faint, thin, edge-on and near-plane splats, and the image
//! does not depend on the tile size.

use tgs_pipelines::{Camera, Gaussians, HostGaussians, RasterKernels, Rasterizer};
use tgs_tests::raster_ref::{splat_reach, RefScene};
use tgs_tests::raster_util::*;
use tgs_tests::*;

/// Tiny, huge, faint, thin, edge-on and near-plane splats, some of them
/// unbounded on screen, seen by `axis_camera(48, 40, 36.0)`.
fn reach_scene(rng: &mut Rng) -> HostGaussians {
    let mut s = HostGaussians::new(3, 16);
    for i in 0..400 {
        let m = [rng.uniform(-1.2, 1.2), rng.uniform(-1.0, 1.0), rng.uniform(1.0, 6.0)].map(|v| v as f32);
        let ls = match i % 8 {
            0 => [(1e-6f32).ln(), (1e-6f32).ln()],
            1 => [(1e-6f32).ln(), -1.5],
            2 => [0.5, -3.0],
            _ => [rng.uniform(-4.0, -1.0) as f32, rng.uniform(-4.0, -1.0) as f32],
        };
        // Opacities from below the cut (culled) to saturated.
        let o = rng.uniform(-7.0, 6.0) as f32;
        s.push(m, ls, random_quat(rng), o, &feats(rng, 48));
    }
    // Huge, and straddling the near plane (unbounded on screen).
    s.push([0.0, 0.0, 8.0], [(1e3f32).ln(), (1e3f32).ln()], [1.0, 0.0, 0.0, 0.0], 0.0, &feats(rng, 48));
    s.push([0.0, 0.0, 0.25], [0.0, 0.0], [0.8, 0.5, 0.0, 0.0], 1.0, &feats(rng, 48));
    s
}

/// The pixel box of every splat, outside which the tile kernels skip it
/// (raster/project.glsl `pixel_box`), holds every pixel the f64 reference
/// sees it reach alpha 1/255 (tiny, huge, faint, thin, edge-on and
/// near-plane splats; the box is computed once per splat, whatever the
/// subgroup size), equals the reference's box where the splat is bounded on
/// screen and well conditioned, and culls pixels of the splats' tiles. A
/// splat whose cutoff ellipse reaches the camera plane is binned to every
/// tile (its 3-sigma square, used before, missed pixels it reaches).
#[test]
fn pixel_boxes_hold_every_reached_pixel() {
    let (ctx, rast, mut rng) = sh3_case("pixel_boxes_hold_every_reached_pixel");
    let cam = axis_camera(48, 40, 36.0);
    let s = reach_scene(&mut rng);
    let g = Gaussians::upload(ctx, &s).unwrap();
    let mut frame = rast.frame(cam.width, cam.height, s.len() as u32, 1024).unwrap();
    rast.forward(&g, &cam, &[0.2; 3], 3, &mut frame, false).unwrap();
    let boxes = frame.download_pixel_boxes(s.len()).unwrap();
    let rects = frame.download_rects(s.len()).unwrap();
    let scene = RefScene::from_host(&s, false);
    let (w, h) = ((cam.width - 1) as f64, (cam.height - 1) as f64);
    let (mut reached, mut compared, mut unbounded) = (0, 0, 0);
    // Pixel centres of the splats' tiles, and of them those in their boxes.
    let (mut in_boxes, mut in_tiles) = (0usize, 0usize);
    for (i, (b, r)) in boxes.iter().zip(&rects).enumerate() {
        let Some(reach) = splat_reach(&scene, &cam, 3, i) else { continue };
        let b = b.map(|v| v as f64);
        let binned = r[2] > r[0] && r[3] > r[1];
        // (A splat binned to no tile is not projected into the buffer.)
        if let Some(want) = reach.pixel_box.filter(|_| binned) {
            compared += 1;
            for k in 0..4 {
                assert!((b[k] - want[k]).abs() <= 1e-3 * (1.0 + want[k].abs()), "Gaussian {i}: box {b:?}, the reference's {want:?}");
            }
        }
        unbounded += !reach.bounded as usize;
        let Some(px) = reach.pixels else { continue };
        reached += 1;
        assert!(binned, "Gaussian {i} reaches pixels {px:?} but has no tiles");
        assert!(b[0] <= px[0] && b[1] <= px[1] && b[2] >= px[2] && b[3] >= px[3], "Gaussian {i}: box {b:?} misses pixels it reaches, {px:?}");
        if !reach.bounded {
            // It can reach any pixel: binned to every tile.
            assert_eq!(*r, [0, 0, frame.tiles_x, frame.tiles_y], "Gaussian {i} is unbounded on screen");
            continue;
        }
        let t = r.map(|v| (v * frame.tile) as f64);
        let count = |lo: f64, hi: f64, tlo: f64, thi: f64, max: f64| {
            let (a, z) = (lo.ceil().max(tlo), hi.floor().min(thi - 1.0).min(max));
            if z >= a {
                (z - a + 1.0) as usize
            } else {
                0
            }
        };
        in_boxes += count(b[0], b[2], t[0], t[2], w) * count(b[1], b[3], t[1], t[3], h);
        in_tiles += count(t[0], t[2], t[0], t[2], w) * count(t[1], t[3], t[1], t[3], h);
    }
    eprintln!("{reached} splats reach a pixel, {unbounded} unbounded on screen; {compared} boxes compared; the bounded ones' boxes hold {in_boxes} of the {in_tiles} pixels of their tiles");
    assert!(reached >= 150 && unbounded >= 1 && compared >= 150, "the scene should hold both kinds of splat");
    // (Measured: about 35% with 16 x 16 tiles, 65% with 8 x 8.)
    assert!(in_boxes * 5 < in_tiles * 4, "the boxes hold {in_boxes} of their tiles' {in_tiles} pixels: they should cull");
    check_validation(ctx);
}

/// Bins `s` seen by `cam` (SH degree `degree`) with each tile layout (16 x
/// 16 tiles with both kernels, 8 x 8 with the Subgroup ones) and checks that
/// every splat is binned only to tiles of its rectangle, once each, and to
/// every tile holding a pixel the f64 reference sees it reach alpha 1/255
/// at. Returns per layout its name, the intersections and the rectangles'
/// tiles.
fn check_binning(s: &HostGaussians, cam: &Camera, degree: u32) -> Vec<(String, usize, usize)> {
    let ctx = ctx_shared();
    let scene = RefScene::from_host(s, false);
    let reach: Vec<_> = (0..s.len()).map(|i| splat_reach(&scene, cam, degree, i)).collect();
    let g = Gaussians::upload(ctx, s).unwrap();
    let mut out = Vec::new();
    for (kernels, small) in [(RasterKernels::Workgroup, false), (RasterKernels::Subgroup, false), (RasterKernels::Subgroup, true)] {
        let rast = Rasterizer::with_options(ctx, 3, SH3, None, kernels).unwrap().small_tiles(small);
        let mut frame = rast.frame(cam.width, cam.height, s.len() as u32, 1024).unwrap();
        rast.forward(&g, cam, &[0.2; 3], degree, &mut frame, false).unwrap();
        let rects = frame.download_rects(s.len()).unwrap();
        let isects = frame.download_intersections().unwrap();
        let what = format!("{kernels:?} kernels, {} x {} tiles", frame.tile, frame.tile);
        let mut binned = vec![std::collections::BTreeSet::new(); s.len()];
        for &(t, i) in &isects {
            assert!(binned[i as usize].insert(t), "{what}: Gaussian {i} binned to tile {t} twice");
        }
        let (tile, tiles_x) = (frame.tile, frame.tiles_x);
        let mut in_rects = 0;
        for (i, r) in rects.iter().enumerate() {
            in_rects += ((r[2] - r[0]) * (r[3] - r[1])) as usize;
            for &t in &binned[i] {
                let (x, y) = (t % tiles_x, t / tiles_x);
                assert!(x >= r[0] && x < r[2] && y >= r[1] && y < r[3], "{what}: Gaussian {i} binned to tile ({x}, {y}) outside its rectangle {r:?}");
            }
            for &(x, y) in reach[i].as_ref().map_or(&[][..], |r| &r.reached[..]) {
                let t = (y / tile) * tiles_x + x / tile;
                assert!(binned[i].contains(&t), "{what}: Gaussian {i} reaches pixel ({x}, {y}) but is not binned to its tile (binned to {:?})", binned[i]);
            }
        }
        out.push((what, isects.len(), in_rects));
    }
    check_validation(ctx);
    out
}

/// A splat is binned only to the tiles of its rectangle it can reach
/// (raster/tile_cull.glsl) and to every tile holding a pixel it reaches
/// (`check_binning`; tiny, huge, faint, thin, edge-on and near-plane
/// splats). On this scene of thin splats at every angle the culling drops
/// a share of the rectangles' tiles.
#[test]
fn binned_tiles_hold_every_reached_pixel() {
    let mut rng = Rng(seed("binned_tiles_hold_every_reached_pixel"));
    let s = reach_scene(&mut rng);
    for (what, binned, in_rects) in check_binning(&s, &axis_camera(48, 40, 36.0), 3) {
        eprintln!("{what}: {binned} intersections of the rectangles' {in_rects} tiles");
        assert!(binned < in_rects, "{what}: {binned} of {in_rects} tiles binned: the culling should drop some");
    }
}

/// A splat whose conic is nearly degenerate (40 units wide, seen nearly
/// edge-on, its bounds millions of pixels across: met in Stage I on a
/// path-traced scene at 600 iterations) keeps every tile of its rectangle:
/// the tile test's f32 conic culled them all, though it reaches the
/// image's corner. The camera and splat are that run's, to the bit.
#[test]
fn an_ill_conditioned_conic_keeps_its_tiles() {
    let cam = Camera {
        width: 50,
        height: 50,
        fx: 60.35534,
        fy: 60.35534,
        cx: 24.5,
        cy: 24.5,
        world_to_view: [[-0.71225935, -0.7019164, 0.0, 4.440892e-16], [-0.21419314, 0.21734934, -0.95230275, 0.47615138], [0.66843694, -0.67828655, -0.30515477, 4.216243]],
    };
    let mut rng = Rng(seed("an_ill_conditioned_conic_keeps_its_tiles"));
    let mut s = HostGaussians::new(3, 16);
    s.push([137.4999, 19.331934, -5.148638], [3.5111022, 3.7653258], [0.38995364, 0.8836341, 0.55414945, 0.9168146], -1.9272645, &feats(&mut rng, 48));
    let reach = splat_reach(&RefScene::from_host(&s, false), &cam, 1, 0).expect("the splat is projected");
    assert!(reach.reached.len() >= 20, "the splat should reach the image's corner ({} pixels)", reach.reached.len());
    check_binning(&s, &cam, 1);
}

/// The image does not depend on the tile size: the Subgroup kernels' 8 x 8
/// and 16 x 16 tiles give the same image bit for bit (a splat is evaluated
/// at the pixels of its box, one unbounded on screen at every pixel: with
/// its 3-sigma square instead, the images differed), and on a scene of
/// ordinary splats the same gradients up to the order of their sums. (On
/// the hard scene a splat straddling the near plane has grazing hits whose
/// terms cancel: its scale gradient moved by up to 1e-3 of the group's
/// norm between the two orders; on the ordinary scene such a splat is rare
/// and moves, the other entries do not.)
#[test]
fn the_image_does_not_depend_on_the_tile_size() {
    let ctx = ctx_shared();
    let mut rng = Rng(seed("the_image_does_not_depend_on_the_tile_size"));
    let cam = axis_camera(48, 40, 36.0);
    let go = random_grads(&mut rng, 3, 48 * 40);
    let run = |s: &HostGaussians, small: bool| {
        let rast = Rasterizer::with_options(ctx, 3, SH3, None, RasterKernels::Subgroup).unwrap().small_tiles(small);
        gpu_run(&rast, s, &cam, &[0.2; 3], 3, Some(&go))
    };
    let hard = reach_scene(&mut rng);
    let mut spec = SceneSpec::new(600, 3, SH3);
    spec.log_scale = (-3.5, -1.5);
    let plain = random_scene(&mut rng, &spec);
    for (what, s) in [("hard", &hard), ("ordinary", &plain)] {
        let (small, wide) = (run(s, true), run(s, false));
        assert_eq!((small.tile, wide.tile), (8, 16));
        assert!(small.intersections > wide.intersections);
        assert_eq!(bits(&small.out), bits(&wide.out), "{what}: the image depends on the tile size");
        if what == "hard" {
            continue;
        }
        let (a, b) = (small.grads.as_ref().unwrap(), wide.grads.as_ref().unwrap());
        for ((name, x), (_, y)) in named_arrays(a).into_iter().zip(named_arrays(b)) {
            // The group norm, as the finite-difference checks measure.
            let size = y.iter().map(|&q| q as f64 * q as f64).sum::<f64>().sqrt();
            // A splat whose gradient is a sum of cancelling terms moves
            // further when they are summed in another order, by more than
            // any bound on the group holds: seed 1796642306289500379 moved
            // one splat's two log-scale gradients (-432.5, 402.0) by 0.24%
            // of their value, 1.8e-3 of the group's norm, while every other
            // entry of the 1,200 stayed within 1e-6 of its own value (an
            // earlier seed, 2.1e-4 of the norm; 60 others within 4.1e-6).
            // So: all but 1% of the entries within 1e-5 of the group's norm.
            let apart = x.iter().zip(y).filter(|(p, q)| ((*p - *q) as f64).abs() > 1e-5 * size).count();
            assert!(size > 0.0, "{name}: no gradient");
            assert!(apart * 100 <= x.len(), "{name} gradients: {apart} of {} entries differ by more than 1e-5 of the norm {size}", x.len());
        }
    }
    check_validation(ctx);
}
