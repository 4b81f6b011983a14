//! `reflection.lambda_mask`: Stage II's loss drawing the reflection set's
//! alpha to the glass masks it was seeded from. On the built-in tiny glass
//! scene (its dataset's masks) it moves the set off the pixels beside the
//! glass; it is part of a resumed Stage II (the masks are read again),
//! bit for bit; without masks it changes nothing; a negative weight is
//! refused by name. The gradient itself is checked against finite
//! differences in tests/tests/reflection.rs (the composite's test).

use std::path::{Path, PathBuf};
use tgs::train::run::{train, TrainArgs};
use tgs_tests::{check_validation, ctx_shared, read_json, TempDir};

#[test]
fn the_mask_loss_draws_the_set_to_the_glass_and_resumes_bit_identically() {
    let ctx = ctx_shared();
    let base = TempDir::new("mask-loss");
    let _ = std::fs::remove_dir_all(&base);
    let stage1 = tgs_tests::tiny_stage1(ctx, &base, 200);
    // Stage II from that Stage I, `iterations` long, with the settings `extra`.
    let stage2 = |tag: &str, iterations: u32, extra: &[&str]| -> PathBuf {
        let out = base.join(tag);
        let mut set = vec![format!("reflection.iterations={iterations}"), "test_interval=0".into(), "checkpoint_interval=0".into()];
        set.extend(extra.iter().map(|s| s.to_string()));
        let a = TrainArgs { out: out.clone(), set, quiet: true, from: Some(stage1.clone()), stages: Some("II".into()), ..Default::default() };
        assert_eq!(train(ctx, &a).unwrap().iteration, 200 + iterations);
        out
    };
    let outside = |run: &Path| -> f64 {
        let t = read_json(&run.join("metrics.json"))["test"].clone();
        t["reflection_outside_mask"].as_f64().unwrap_or_else(|| panic!("no reflection_outside_mask in {t}"))
    };
    let off = stage2("off", 40, &[]);
    let on = stage2("on", 40, &["reflection.lambda_mask=20"]);
    let (o_off, o_on) = (outside(&off), outside(&on));
    assert!(o_on < o_off, "the share of the set's pixels off the glass: {o_on} with the mask loss, {o_off} without");
    let ply = |run: &Path| std::fs::read(run.join("reflection.ply")).unwrap();

    // Ended halfway and resumed (reflection.iterations is a setting
    // --resume may change): the same set, bit for bit.
    let part = stage2("part", 20, &["reflection.lambda_mask=20"]);
    let resume = TrainArgs { out: part.clone(), resume: true, set: vec!["reflection.iterations=40".into()], quiet: true, ..Default::default() };
    assert_eq!(train(ctx, &resume).unwrap().iteration, 240);
    assert!(ply(&part) == ply(&on), "a resumed Stage II with the mask loss differs from the uninterrupted one");

    // Seeded from the residual (no masks): the weight changes nothing.
    let r0 = stage2("residual-off", 5, &["reflection.dataset_masks=false"]);
    let r1 = stage2("residual-on", 5, &["reflection.dataset_masks=false", "reflection.lambda_mask=20"]);
    assert!(ply(&r0) == ply(&r1), "the mask loss acted without masks");

    let a = TrainArgs {
        out: base.join("refused"),
        set: vec!["reflection.lambda_mask=-1".into()],
        quiet: true,
        from: Some(stage1.clone()),
        stages: Some("II".into()),
        ..Default::default()
    };
    let e = format!("{:#}", train(ctx, &a).expect_err("a negative weight is refused"));
    assert!(e.contains("reflection.lambda_mask") && e.contains("-1"), "{e}");
    let _ = std::fs::remove_dir_all(&base);
    check_validation(ctx);
}
