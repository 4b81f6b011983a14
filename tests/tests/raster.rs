//! The 2DGS rasterizer against the CPU f64 reference (forward) and central
//! finite differences of it (gradients), plus determinism, multi-span tiles
//! and the hard cases. CI runs this at subgroup 8 and 4.

use tgs_pipelines::{Features, Rasterizer};
use tgs_tests::raster_util::*;
use tgs_tests::*;

const SH3: Features = Features::Sh { degree: 3 };

#[test]
fn forward_matches_cpu_random_scenes() {
    let ctx = ctx_shared();
    let rast = Rasterizer::new(ctx, 3, SH3).unwrap();
    let mut rng = Rng(seed("forward_matches_cpu_random_scenes"));
    for (w, h, n) in [(70, 45, 300), (16, 16, 50), (33, 17, 120)] {
        let scene = random_scene(&mut rng, &SceneSpec::new(n, 3, SH3));
        let cam = default_camera(w, h);
        check_forward(&rast, &scene, &cam, &[0.1, 0.5, 0.9], 3, &format!("{w}x{h} n={n}"));
    }
    check_validation(ctx);
}

#[test]
fn gradients_match_finite_differences_sh3() {
    let ctx = ctx_shared();
    let rast = Rasterizer::new(ctx, 3, SH3).unwrap();
    let mut rng = Rng(seed("gradients_match_finite_differences_sh3"));
    let mut spec = SceneSpec::new(12, 3, SH3);
    spec.log_scale = (-2.2, -1.0);
    let scene = random_scene(&mut rng, &spec);
    let cam = default_camera(40, 24);
    check_gradients(&rast, &scene, &cam, &[0.2, 0.3, 0.7], 3, &mut rng, &[], "sh3");
    check_validation(ctx);
}
