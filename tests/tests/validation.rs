//! The validation slice (`validation_every`, issue 77): the views it holds
//! out reach no later stage (changing their images leaves Stages II and
//! III bit for bit as they were, changing a training view's does not), and
//! the rule on Stage II: a set that does not raise their PSNR by the
//! margin is dropped (Stage I's model is the result, and stays so on
//! --resume), one that does is kept.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use tgs::train::checkpoint;
use tgs::train::run::{load_dataset, train, TrainArgs};
use tgs::train::Trainer;
use tgs_tests::{check_validation, ctx_shared};

/// The driver's stop flag is process-wide: one driver run at a time.
static DRIVER: Mutex<()> = Mutex::new(());

fn scene() -> PathBuf {
    tgs_tests::tiny_glass_scene(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("validation-scene"))
}

fn args(out: &Path, margin: f32) -> TrainArgs {
    let set = [
        "iterations=120".to_string(),
        "reflection.iterations=40".into(),
        "light_field.iterations=40".into(),
        "validation_every=4".into(),
        format!("validation_margin_db={margin}"),
        "test_interval=0".into(),
        "checkpoint_interval=0".into(),
    ];
    let _ = std::fs::remove_dir_all(out);
    TrainArgs { dataset: Some(scene()), out: out.to_path_buf(), preset: Some("quick".into()), set: set.to_vec(), quiet: true, ..Default::default() }
}

/// Stages II and III from `run`'s Stage I checkpoint on `data` with
/// `edit` applied to its training images: every array of the end state.
fn later_stages(run: &Path, edit: impl Fn(usize, &mut Vec<f32>)) -> Vec<Vec<u32>> {
    let ctx = ctx_shared();
    let path = run.join("checkpoint-stage1.bin");
    let (h, arrays) = checkpoint::read(&path).unwrap();
    let mut data = load_dataset(Path::new(&h.dataset), &h.config).unwrap();
    for (i, v) in data.train.iter_mut().enumerate() {
        edit(i, &mut v.image.data);
    }
    let mut tr: Trainer = checkpoint::restore(ctx, &path, (h, arrays), &data).unwrap();
    while !tr.done() {
        if tr.next_begins().is_some() {
            tr.begin_next(None, true).unwrap();
        } else {
            tr.step(false).unwrap();
        }
    }
    let mut out: Vec<Vec<u32>> = tr.scattering.set.params.buffers().iter().map(|b| b.download().unwrap().iter().map(|x| x.to_bits()).collect()).collect();
    let later = tr.later.as_ref().expect("Stage III ran");
    out.extend(later.set().params.buffers().iter().map(|b| b.download().unwrap().iter().map(|x| x.to_bits()).collect::<Vec<u32>>()));
    out
}

#[test]
fn validation_views_reach_no_later_stage() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let base = tgs_tests::TempDir::created("validation-isolation");
    let run = base.join("run");
    train(ctx_shared(), &args(&run, -100.0)).unwrap();
    let plain = later_stages(&run, |_, _| {});
    assert_eq!(later_stages(&run, |_, _| {}), plain, "Stages II and III rerun differently");
    // Views 3, 7, 11, 15 are the validation views of 16 (every 4th).
    let grey = |img: &mut Vec<f32>| img.iter_mut().for_each(|v| *v = 0.5);
    assert_eq!(
        later_stages(&run, |i, img| if i % 4 == 3 {
            grey(img)
        }),
        plain,
        "a validation view's image changed Stages II / III"
    );
    assert_ne!(
        later_stages(&run, |i, img| if i == 2 {
            grey(img)
        }),
        plain,
        "a training view's image changed nothing: the test cannot tell"
    );
    check_validation(ctx_shared());
}

fn metrics(run: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(run.join("metrics.json")).unwrap()).unwrap()
}

#[test]
fn stage_two_is_kept_only_on_validation_evidence() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = ctx_shared();
    let base = tgs_tests::TempDir::created("validation-gate");
    // A margin no set can clear: Stage II is dropped and Stage I's model is the result.
    let dropped = base.join("dropped");
    let o = train(ctx, &args(&dropped, 100.0)).unwrap();
    let m = metrics(&dropped);
    assert_eq!(m["reflection"]["kept"], false, "{}", m["reflection"]);
    let v = &m["validation"];
    assert_eq!((v["every"].as_u64(), v["views"].as_u64()), (Some(4), Some(4)));
    let stages: Vec<&str> = v["stages"].as_array().unwrap().iter().map(|s| s["stage"].as_str().unwrap()).collect();
    assert_eq!(stages, ["I", "II"], "Stage III ran after a dropped Stage II");
    let stage_one = m["stages"].as_array().unwrap().iter().find(|s| s["stage"] == "I").unwrap();
    assert_eq!(m["test"]["psnr"], stage_one["test"]["psnr"], "the result is not Stage I's model");
    assert!(!dropped.join("reflection.ply").exists() && !dropped.join("light_field.safetensors").exists());
    assert!(std::fs::read_to_string(dropped.join("log.jsonl")).unwrap().contains("\"event\":\"dropped\""));
    // Resumed, the run stays finished with Stage I's model.
    let again = train(ctx, &TrainArgs { out: dropped.to_path_buf(), resume: true, quiet: true, ..Default::default() }).unwrap();
    assert_eq!(again.iteration, o.iteration);
    assert_eq!(metrics(&dropped)["test"]["psnr"], stage_one["test"]["psnr"]);
    let (tr, _) = tgs::train::run::open_run(ctx, &dropped).unwrap();
    assert!(tr.later.is_none());
    drop(tr);
    // Any gain clears a margin of -100 dB: kept, Stage III follows.
    let kept = base.join("kept");
    train(ctx, &args(&kept, -100.0)).unwrap();
    let m = metrics(&kept);
    assert_eq!(m["reflection"]["kept"], true);
    assert_eq!(m["validation"]["stages"].as_array().unwrap().len(), 3);
    assert!(kept.join("reflection.ply").is_file() && kept.join("light_field.safetensors").is_file());
    check_validation(ctx);
}
