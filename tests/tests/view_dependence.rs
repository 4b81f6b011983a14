//! The view-dependence measure of the Stage I residual
//! (harness/train/src/train/stages/reflection/view_dependence.rs), on the CPU: a ring of views over
//! a ground plane with analytic depths, and residuals that depend on the
//! surface point only (Stage I misfit), on the view only (reflection), or
//! come from an occluded view.

use tgs::train::stages::reflection::view_dependence::{view_dependence, VdMap};
use tgs_pipelines::Camera;

fn ring(n: usize, radius: f32, height: f32, w: u32, h: u32) -> Vec<Camera> {
    (0..n)
        .map(|i| {
            let a = i as f32 / n as f32 * std::f32::consts::TAU;
            Camera::look_at([radius * a.cos(), radius * a.sin(), height], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.8, w, h)
        })
        .collect()
}

/// Depth of the ground plane z = 0 per pixel (0 where the ray misses it)
/// and its world points.
fn ground(cam: &Camera) -> (Vec<f32>, Vec<[f32; 3]>) {
    let o = cam.centre();
    let (mut depth, mut pts) = (Vec::new(), Vec::new());
    for v in 0..cam.height {
        for u in 0..cam.width {
            let p = cam.unproject(u as f32, v as f32, 1.0);
            let dz = p[2] - o[2];
            let t = if dz < 0.0 { -o[2] / dz } else { 0.0 };
            depth.push(t);
            pts.push([0, 1, 2].map(|k| o[k] + t * (p[k] - o[k])));
        }
    }
    (depth, pts)
}

/// A view with residual `f(view index, world point)` (3 planes).
fn map(i: usize, cam: &Camera, f: &dyn Fn(usize, [f32; 3]) -> [f32; 3], max_side: u32) -> VdMap {
    let (depth, pts) = ground(cam);
    let n = pts.len();
    let mut r = vec![0.0f32; 3 * n];
    for (j, x) in pts.iter().enumerate() {
        let v = f(i, *x);
        for c in 0..3 {
            r[c * n + j] = v[c];
        }
    }
    VdMap::new(cam, &r, &depth, max_side)
}

fn maps(cams: &[Camera], f: &dyn Fn(usize, [f32; 3]) -> [f32; 3], max_side: u32) -> Vec<VdMap> {
    cams.iter().enumerate().map(|(i, c)| map(i, c, f, max_side)).collect()
}

const SPHERE: ([f32; 3], f32) = ([0.0, 0.0, 1.5], 4.5);

#[test]
fn a_residual_fixed_to_the_surface_has_little_spread_and_one_that_follows_the_view_has_its_own() {
    let cams = ring(12, 4.0, 1.5, 64, 48);
    // Stage I misfit: a smooth function of the surface point.
    let misfit = |_: usize, x: [f32; 3]| [0.05 * (2.0 * x[0]).sin(), 0.03 * (3.0 * x[1]).cos(), 0.02 * x[0] * x[1]];
    let a = view_dependence(&maps(&cams, &misfit, 128), SPHERE, 1 << 16);
    assert!(a.samples > 5000, "{a:?}");
    assert!(a.spread < 0.004, "surface-fixed residual spreads {}", a.spread);
    // A reflection: the same point's residual is +0.05 in even views and
    // -0.05 in odd ones (mean absolute deviation 0.05 where both are seen).
    let refl = |i: usize, x: [f32; 3]| {
        let s = if i.is_multiple_of(2) { 0.05 } else { -0.05 };
        let m = misfit(i, x);
        [m[0] + s, m[1] + s, m[2] + s]
    };
    let b = view_dependence(&maps(&cams, &refl, 128), SPHERE, 1 << 16);
    assert_eq!(a.samples, b.samples, "the same surface points are measured");
    assert!(b.spread > 0.035 && b.spread < 0.052, "view-dependent residual spreads {}", b.spread);
    // Deterministic.
    assert_eq!(view_dependence(&maps(&cams, &refl, 128), SPHERE, 1 << 16), b);
}

#[test]
fn occluded_views_far_surfaces_and_empty_input_do_not_count() {
    let cams = ring(12, 4.0, 1.5, 64, 48);
    let misfit = |_: usize, x: [f32; 3]| [0.05 * (2.0 * x[0]).sin(), 0.0, 0.0];
    let base = view_dependence(&maps(&cams, &misfit, 128), SPHERE, 1 << 16);
    // One more view whose Stage I surface is an occluder at 60% of the
    // ground's depth, with a residual of 1 everywhere: it sees none of the
    // ground points, so it adds nothing to their spread. Its own occluder
    // points, in front of the ground, are seen by no other view: no sample.
    let extra = Camera::look_at([4.0, 0.5, 1.5], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0], 0.8, 64, 48);
    let (depth, _) = ground(&extra);
    let near: Vec<f32> = depth.iter().map(|d| 0.6 * d).collect();
    let n = near.len();
    let mut all = maps(&cams, &misfit, 128);
    all.push(VdMap::new(&extra, &vec![1.0f32; 3 * n], &near, 128));
    let with = view_dependence(&all, SPHERE, 1 << 16);
    assert!((with.spread - base.spread).abs() < 1e-12, "{with:?} vs {base:?}");
    // Surface points outside the camera sphere are not measured.
    let far = view_dependence(&maps(&cams, &misfit, 128), ([0.0, 0.0, 1.5], 1.0), 1 << 16);
    assert_eq!((far.samples, far.spread), (0, 0.0));
    // Nothing to measure.
    assert_eq!(view_dependence(&[], SPHERE, 1 << 16).samples, 0);
    assert_eq!(view_dependence(&maps(&cams, &misfit, 128), SPHERE, 0).samples, 0);
    // Views with no surface (sky everywhere).
    let sky: Vec<VdMap> = cams.iter().map(|c| VdMap::new(c, &vec![0.3f32; 3 * 64 * 48], &vec![0.0f32; 64 * 48], 128)).collect();
    assert_eq!(view_dependence(&sky, SPHERE, 1 << 16).samples, 0);
}

#[test]
fn large_views_are_reduced_and_measure_the_same() {
    // 256 x 192 views reduced to 128 x 96 (residual box-averaged, depth at
    // the block centre) against views rendered at 128 x 96 directly.
    let big = ring(12, 4.0, 1.5, 256, 192);
    let small = ring(12, 4.0, 1.5, 128, 96);
    let refl = |i: usize, x: [f32; 3]| {
        let s = if i.is_multiple_of(3) { 0.04 } else { -0.02 };
        [0.05 * (2.0 * x[0]).sin() + s, s, s]
    };
    let reduced = maps(&big, &refl, 128);
    assert_eq!((reduced[0].camera.width, reduced[0].camera.height), (128, 96));
    assert_eq!(reduced[0].residual.len(), 3 * 128 * 96);
    let a = view_dependence(&reduced, SPHERE, 1 << 16);
    let b = view_dependence(&maps(&small, &refl, 128), SPHERE, 1 << 16);
    assert!(a.samples > 5000 && b.samples > 5000, "{a:?} {b:?}");
    assert!((a.spread - b.spread).abs() < 0.1 * b.spread, "reduced {} vs direct {}", a.spread, b.spread);
    // Fewer samples, about the same measure.
    let c = view_dependence(&reduced, SPHERE, 2000);
    assert!(c.samples <= 2000 && c.samples > 500, "{c:?}");
    assert!((c.spread - a.spread).abs() < 0.15 * a.spread, "{} vs {}", c.spread, a.spread);
}
