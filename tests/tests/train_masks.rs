//! The glass masks a dataset gives for its training views (`mask_path` in
//! transforms_train.json; `reflection.dataset_masks`, on by default): Stage
//! II seeds from them exactly as from the same masks given as a directory
//! (`reflection.seed_masks`), bit for bit, and metrics.json records where
//! they came from, and from how many views. A view without a mask takes
//! no part in the seeding; turned off, the seeds come from the residual;
//! masks that mark no glass anywhere skip Stage II.

use std::path::PathBuf;
use tgs::train::run::{train, TrainArgs};
use tgs_tests::{check_validation, ctx_shared, read_json as json, TempDir};

fn sets(s: &[&str]) -> Vec<String> {
    s.iter().map(|s| s.to_string()).collect()
}

#[test]
fn stage_two_seeds_from_the_datasets_training_masks() {
    let ctx = ctx_shared();
    let base = TempDir::new("train-masks");
    let _ = std::fs::remove_dir_all(&base);
    let stage1 = tgs_tests::tiny_stage1(ctx, &base, 200);
    let scene = base.join("scene");
    // One Stage II step from that Stage I with the settings `extra`: the
    // decision metrics.json records and reflection.ply's bytes.
    let step = |tag: &str, extra: Vec<String>| -> (serde_json::Value, Vec<u8>) {
        let out = base.join(tag);
        let mut set = sets(&["reflection.iterations=1", "test_interval=0"]);
        set.extend(extra);
        let a = TrainArgs { out: out.clone(), set, quiet: true, from: Some(stage1.clone()), stages: Some("II".into()), ..Default::default() };
        assert_eq!(train(ctx, &a).unwrap().iteration, 201);
        (json(&out.join("metrics.json"))["reflection"].clone(), std::fs::read(out.join("reflection.ply")).unwrap())
    };

    // The default: the dataset's masks, and the share of the pixels they mark.
    let (dd, dataset_ply) = step("dataset", vec![]);
    assert_eq!(dd["seed_mask_source"], "dataset", "{dd}");
    let n = dd["seed_mask_views"][1].as_u64().unwrap();
    assert_eq!(dd["seed_mask_views"], serde_json::json!([n, n]));
    let masks = base.join("masks");
    std::fs::create_dir_all(&masks).unwrap();
    let (mut glass, mut all) = (0usize, 0usize);
    let mut i = 0;
    while scene.join(format!("train/r_{i}_mask.png")).is_file() {
        let src = scene.join(format!("train/r_{i}_mask.png"));
        let (_, _, m) = tgs::data::image_io::read_mask(&src).unwrap();
        glass += m.iter().filter(|&&g| g).count();
        all += m.len();
        std::fs::copy(&src, masks.join(format!("r_{i}.png"))).unwrap();
        i += 1;
    }
    assert!(i > 0 && glass > 0);
    let coverage = dd["seed_mask_coverage"].as_f64().unwrap();
    assert!((coverage - glass as f64 / all as f64).abs() < 1e-12, "{dd}");

    // The same masks as a directory: the same seeds, bit for bit.
    let (dm, dir_ply) = step("dir", vec![format!("reflection.seed_masks={}", masks.display())]);
    assert_eq!(dm["seed_mask_source"].as_str().map(PathBuf::from), Some(masks.clone()), "{dm}");
    assert_eq!(dm["seed_mask_coverage"], dd["seed_mask_coverage"]);
    assert!(dataset_ply == dir_ply, "the dataset's masks seed differently from the same masks in a directory");
    // Marked in `tgs view` as a flat pane (a large square in z = 0 here):
    // the seeds lie on it (reflection.seed_panes), recorded; turned off,
    // the masks' hull seeds as before, bit for bit.
    let pane = r#"{"regions": [{"flat": true, "outlines": [], "pane": {"corners": [[-50, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]]}}]}"#;
    std::fs::write(masks.join("marks.json"), pane).unwrap();
    let (dp, pane_ply) = step("pane", vec![format!("reflection.seed_masks={}", masks.display())]);
    assert!(dp["seed_panes"][0] == 1 && dp["seed_panes"][1] == dp["seeds"] && dp["seeds"].as_u64().unwrap() > 0, "{dp}");
    assert!(dp.get("seed_rim").is_none_or(|r| r[1] == 0) && pane_ply != dir_ply, "{dp}");
    let (doff, off_ply) = step("pane-off", vec![format!("reflection.seed_masks={}", masks.display()), "reflection.seed_panes=false".into()]);
    assert!(doff.get("seed_panes").is_none() && off_ply == dir_ply, "{doff}");
    std::fs::remove_file(masks.join("marks.json")).unwrap();
    // The masks of every 4th view alone: those seed, at a looser
    // significance that so few views can beat (1e-6 needs more).
    let sparse = base.join("sparse");
    std::fs::create_dir_all(&sparse).unwrap();
    for k in (0..i).step_by(4) {
        std::fs::copy(masks.join(format!("r_{k}.png")), sparse.join(format!("r_{k}.png"))).unwrap();
    }
    let (ds, _) = step("sparse", vec![format!("reflection.seed_masks={}", sparse.display())]);
    assert_eq!(ds["seed_mask_views"], serde_json::json!([n.div_ceil(4), n]));
    assert!(ds["seed_significance"].as_f64().is_some_and(|a| a > 1e-6) && ds["significance_dropped"] == false && ds["seeds"].as_u64().unwrap() > 0, "{ds}");
    // Glass over every pixel of every view: nothing is carved, so no ray
    // reaches a hull and the set starts as Stage I's copy, finite.
    let full = base.join("all-glass");
    std::fs::create_dir_all(&full).unwrap();
    for k in 0..i {
        let (w, h, _) = tgs::data::image_io::read_mask(&masks.join(format!("r_{k}.png"))).unwrap();
        tgs::data::image_io::write_mask(&full.join(format!("r_{k}.png")), w, h, &vec![true; (w * h) as usize]).unwrap();
    }
    let (df, _) = step("all-glass", vec![format!("reflection.seed_masks={}", full.display())]);
    assert!(df["seed_mask_coverage"] == 1.0 && df["hull_empty"] == true && df["copied"].as_u64().unwrap() > 0, "{df}");
    let test = &json(&base.join("all-glass/metrics.json"))["test"];
    assert!(test["psnr"].as_f64().is_some_and(f64::is_finite) && test["normal_mae_deg"].as_f64().is_some_and(f64::is_finite), "{test}");
    // A directory with no view's mask is refused, naming it.
    let empty = base.join("no-masks");
    std::fs::create_dir_all(&empty).unwrap();
    let a = TrainArgs {
        out: base.join("refused"),
        set: vec![format!("reflection.seed_masks={}", empty.display())],
        quiet: true,
        from: Some(stage1.clone()),
        stages: Some("II".into()),
        ..Default::default()
    };
    let e = format!("{:#}", train(ctx, &a).expect_err("a directory without masks is refused"));
    assert!(e.contains("no-masks") && e.contains("no glass mask") && e.contains("r_0.png"), "{e}");
    // The views' image folder, its files named as their masks would be: refused, not read as masks.
    let a = TrainArgs { set: vec![format!("reflection.seed_masks={}", scene.join("train").display())], ..a };
    let e = format!("{:#}", train(ctx, &a).expect_err("colour images are refused as masks"));
    assert!(e.contains("colour image") && e.contains("r_0.png"), "{e}");

    // Turned off: the residual's seeds, recorded without masks.
    let (dr, residual_ply) = step("residual", sets(&["reflection.dataset_masks=false"]));
    assert!(dr.get("seed_mask_coverage").is_none() && dr.get("seed_mask_source").is_none(), "{dr}");
    assert!(dr["seeds"].as_u64().unwrap() > 0 && residual_ply != dataset_ply);
    // The paper's copy start has no hull to seed: the masks are not used
    // and nothing is refused.
    let (dc, _) = step("copy", sets(&["reflection.init=\"copy\""]));
    assert!(dc.get("seed_mask_source").is_none() && dc["copied"].as_u64().unwrap() > 0, "{dc}");

    // A dataset with a mask for every 4th training view only: those seed.
    let partial = base.join("partial");
    tgs_tests::copy_dir(&scene, &partial);
    let tf = partial.join("transforms_train.json");
    let mut doc = json(&tf);
    for (k, f) in doc["frames"].as_array_mut().unwrap().iter_mut().enumerate() {
        if k % 4 != 0 {
            f.as_object_mut().unwrap().remove("mask_path");
        }
    }
    std::fs::write(&tf, serde_json::to_string(&doc).unwrap()).unwrap();
    let out = base.join("partial-run");
    let a = TrainArgs {
        dataset: Some(partial),
        out: out.clone(),
        preset: Some("quick".into()),
        set: sets(&[
            "stages=\"I,II\"",
            "iterations=20",
            "reflection.iterations=1",
            "reflection.min_residual=0",
            "reflection.min_view_dependence=0",
            "test_interval=0",
            "checkpoint_interval=0",
        ]),
        quiet: true,
        ..Default::default()
    };
    assert_eq!(train(ctx, &a).unwrap().iteration, 21);
    let dp = json(&out.join("metrics.json"))["reflection"].clone();
    assert!(dp["run"] == true && dp["seed_mask_source"] == "dataset" && dp["seed_mask_views"] == serde_json::json!([n.div_ceil(4), n]), "{dp}");

    // Masks that mark no glass in any training view: no reflection set,
    // though the residual alone (thresholds 0) would have run one.
    let blank = base.join("blank");
    tgs_tests::copy_dir(&scene, &blank);
    for k in 0..i {
        let m = blank.join(format!("train/r_{k}_mask.png"));
        let (w, h, _) = tgs::data::image_io::read_mask(&m).unwrap();
        tgs::data::image_io::write_mask(&m, w, h, &vec![false; (w * h) as usize]).unwrap();
    }
    let out = base.join("blank-run");
    let a = TrainArgs { dataset: Some(blank), out: out.clone(), ..a };
    assert_eq!(train(ctx, &a).unwrap().iteration, 20);
    let m = json(&out.join("metrics.json"));
    let db = &m["reflection"];
    assert!(db["run"] == false && db["seed_mask_coverage"] == 0.0 && db["seed_mask_source"] == "dataset", "{db}");
    assert_eq!(m["stages"].as_array().unwrap().len(), 1, "{m}");
    let _ = std::fs::remove_dir_all(&base);
    check_validation(ctx);
}
