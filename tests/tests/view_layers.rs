//! The viewer's layers of a run's checkpoint, without a window: before a
//! stage has rendered once the viewer guesses which layers it has (a later
//! stage's); one it lacks (Stage II has no `phi_mask`) is stepped over
//! when drawn, to the next the stage has, with no stage named in the viewer.

use std::path::Path;
use tgs::train::run::{train, TrainArgs};
use tgs::view::scene::Scene;
use tgs_pipelines::PixelOrder;
use tgs_tests::ctx_shared;

#[test]
fn a_layer_the_stage_lacks_is_stepped_over_when_drawn() {
    let ctx = ctx_shared();
    let base = tgs_tests::TempDir::new("view-layers");
    let scene = tgs_tests::tiny_glass_scene(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("view-layers-scene"));
    let run = base.join("run");
    let set = ["iterations=200", "reflection.iterations=20", "test_interval=0", "checkpoint_interval=0"].map(String::from).to_vec();
    let a = TrainArgs { dataset: Some(scene), out: run.clone(), preset: Some("quick".into()), set, stages: Some("I,II".into()), quiet: true, ..Default::default() };
    assert_eq!(train(ctx, &a).unwrap().iteration, 220);

    let mut s = Scene::open(ctx, &run).unwrap();
    assert_eq!(s.stage(), "II");
    let (_, cam) = s.dataset_camera();
    // Nothing rendered yet: from F0 the next guess is phi_mask.
    s.show_layer("F0");
    assert_eq!(s.layer_name(), "F0");
    s.step_layer(1);
    assert_eq!(s.layer_name(), "phi_mask");
    let px = s.host_layer(&cam, Some(&cam), PixelOrder::Rgba).unwrap();
    assert_eq!(s.layer_name(), "normal_scat", "Stage II has no phi_mask: the next layer it has is drawn");
    assert_eq!(px.len(), (cam.width * cam.height) as usize);
    // Now the stage's layers are known: stepping back skips phi_mask (and
    // F0, which the quick preset's Stage II without Fresnel lacks too), and
    // the layer it lands on is drawn as it is.
    s.step_layer(-1);
    assert_eq!(s.layer_name(), "R");
    s.host_layer(&cam, Some(&cam), PixelOrder::Rgba).unwrap();
    assert_eq!(s.layer_name(), "R");
}
