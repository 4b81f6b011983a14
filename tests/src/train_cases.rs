//! Cases the training-kernel suites share (tests/tests/train_kernels.rs,
//! tests/tests/slices.rs): the eight densification cases and the
//! fused-reduce case.

use crate::{ctx_shared, seed, Rng};
use tgs_pipelines::{Adam, AdamGroup, HostGaussians};

/// Eight Gaussians, one per densification case, with their gradient
/// accumulators, view counts and screen radii.
pub fn densify_cases() -> (HostGaussians, Vec<f32>, Vec<f32>, Vec<f32>) {
    let mut g = HostGaussians::new(3, 4);
    let logit = |o: f32| (o / (1.0 - o)).ln();
    // (opacity, log-scale, mean grad, views, max radius)
    let spec: [(f32, f32, f32, f32, f32); 8] = [
        (0.5, -4.0, 1e-5, 3.0, 4.0),  // 0 keep
        (0.5, -4.0, 5e-4, 2.0, 4.0),  // 1 clone
        (0.5, -1.0, 5e-4, 2.0, 4.0),  // 2 split
        (0.01, -4.0, 1e-5, 2.0, 4.0), // 3 prune: opacity
        (0.5, 0.5, 1e-5, 2.0, 4.0),   // 4 prune: world size
        (0.5, -4.0, 1e-5, 2.0, 40.0), // 5 prune: screen size
        (0.5, -4.0, 1.0, 0.0, 0.0),   // 6 never seen: keep
        (0.5, -2.5, 3e-4, 1.0, 4.0),  // 7 split (scale 0.082 > 0.01 * extent)
    ];
    let (mut acc, mut den, mut rad) = (vec![], vec![], vec![]);
    for (i, &(o, ls, gr, views, r)) in spec.iter().enumerate() {
        let feats: Vec<f32> = (0..12).map(|k| (i * 12 + k) as f32 * 0.01).collect();
        g.push([i as f32, 0.5 * i as f32, -0.25 * i as f32], [ls, ls - 0.3], [0.9, 0.1 * i as f32, 0.2, -0.3], logit(o), &feats);
        acc.push(if views > 0.0 { gr * views } else { 1.0 });
        den.push(views);
        rad.push(r);
    }
    (g, acc, den, rad)
}

/// The fused-reduce tests' Adam groups: one rate per geometry array; the
/// SH colour's DC and rest at their own rates, the coefficients of degree
/// 1 of 3 active.
pub fn fused_groups() -> [AdamGroup; 5] {
    fused_groups_of(3)
}

/// [`fused_groups`] for a set of SH degree `degree` (degree 1 active, or
/// all of a degree-0 set).
fn fused_groups_of(degree: u32) -> [AdamGroup; 5] {
    let coeffs = (degree + 1) * (degree + 1);
    [
        AdamGroup::single(1e-3),
        AdamGroup::single(5e-3),
        AdamGroup::single(1e-3),
        AdamGroup::single(0.05),
        AdamGroup { active: 3 * coeffs.min(4), ..AdamGroup::split(2.5e-3, 1.25e-4, 3 * coeffs, 3) },
    ]
}

/// The fused-reduce tests' case: 400 random Gaussians of SH degree 3 (the
/// rng seeded by the test's name), a 70 x 45 view and a random image
/// gradient, Adam and its groups.
pub struct FusedCase {
    pub host: HostGaussians,
    pub cam: tgs_pipelines::Camera,
    pub grad_out: Vec<f32>,
    pub adam: Adam,
    pub groups: [AdamGroup; 5],
}

pub fn fused_case(name: &str) -> FusedCase {
    fused_case_of(name, 3)
}

/// [`fused_case`] with Gaussians of SH degree `degree`: at degree 0 a
/// Gaussian has 3 features, which the CPU reduce cannot step four at a
/// time (at degree 3 it has 48).
pub fn fused_case_of(name: &str, degree: u32) -> FusedCase {
    use crate::raster_util::{default_camera, random_grads, random_scene, SceneSpec};
    use tgs_pipelines::Features;
    let mut rng = Rng(seed(name));
    let host = random_scene(&mut rng, &SceneSpec::new(400, 3, Features::Sh { degree }));
    let cam = default_camera(70, 45);
    let grad_out = random_grads(&mut rng, 3, 70 * 45);
    FusedCase { host, cam, grad_out, adam: Adam::new(ctx_shared(), 1e-15).unwrap(), groups: fused_groups_of(degree) }
}
