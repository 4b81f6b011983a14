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

/// The vertex count of a PLY file's header.
fn ply_vertices(path: &Path) -> u64 {
    let bytes = std::fs::read(path).unwrap();
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(4096)]).to_string();
    head.lines().find_map(|l| l.strip_prefix("element vertex ")).and_then(|n| n.trim().parse().ok()).unwrap()
}

#[test]
fn stage_two_pieces_are_judged_and_those_not_kept_removed() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = ctx_shared();
    let base = tgs_tests::TempDir::created("validation-pieces");
    let with = |out: &Path, z: f32, stages: &str| {
        let mut a = args(out, 0.0);
        // Long enough for Stage II to raise the validation PSNR as a whole.
        let longer = ["iterations=400".to_string(), "reflection.iterations=200".into()];
        a.set.extend(longer.into_iter().chain([format!("reflection.validation_z={z}"), "reflection.validation_cells=4".into(), format!("stages=\"{stages}\"")]));
        a
    };
    // Some benefit of the doubt (z = -1): the pieces whose removal changes
    // no validation pixel, or makes it better by a standard error, go.
    let run = base.join("doubt");
    train(ctx, &with(&run, -1.0, "I,II")).unwrap();
    let m = metrics(&run);
    let pieces = m["reflection"]["pieces"].as_array().unwrap_or_else(|| panic!("no pieces: {}", m["reflection"]));
    assert!(pieces.len() > 1, "{pieces:?}");
    let kept: Vec<&serde_json::Value> = pieces.iter().filter(|p| p["kept"] == true).collect();
    assert!(!kept.is_empty() && kept.len() < pieces.len(), "the tiny glass keeps some pieces and drops others: {pieces:?}");
    for p in pieces {
        let (gain, z, pixels) = (p["gain_db"].as_f64().unwrap(), p["z"].as_f64().unwrap(), p["pixels"].as_u64().unwrap());
        assert!(gain.is_finite() && z.is_finite());
        if pixels == 0 {
            assert_eq!(p["kept"], false, "a piece that changes nothing stays: {p}");
        }
    }
    let kept_gaussians: u64 = kept.iter().map(|p| p["gaussians"].as_u64().unwrap()).sum();
    assert_eq!(ply_vertices(&run.join("reflection.ply")), kept_gaussians, "the set written is not the kept pieces");
    let stage_two = m["validation"]["stages"].as_array().unwrap().iter().find(|s| s["stage"] == "II").unwrap().clone();
    assert_eq!(m["reflection"]["kept"], true, "{stage_two}");
    let rec = m["stages"].as_array().unwrap().iter().find(|s| s["stage"] == "II").unwrap();
    assert_eq!(rec["validation"]["pieces_kept"].as_u64(), Some(kept.len() as u64));
    assert!(std::fs::read_to_string(run.join("log.jsonl")).unwrap().contains("\"event\":\"pieces\""));
    // Rerun: the same verdicts and the same set, bit for bit.
    let again = base.join("again");
    train(ctx, &with(&again, -1.0, "I,II")).unwrap();
    assert_eq!(metrics(&again)["reflection"]["pieces"], m["reflection"]["pieces"]);
    assert_eq!(std::fs::read(again.join("reflection.ply")).unwrap(), std::fs::read(run.join("reflection.ply")).unwrap());
    // Sure of every gain (z = 10): no piece is, so Stage II is dropped
    // whatever its whole-image PSNR, and Stage III does not run.
    let sure = base.join("sure");
    train(ctx, &with(&sure, 10.0, "I,II,III")).unwrap();
    let m = metrics(&sure);
    assert!(m["reflection"]["pieces"].as_array().unwrap().iter().all(|p| p["kept"] == false), "{}", m["reflection"]);
    assert_eq!(m["reflection"]["kept"], false);
    let stages: Vec<&str> = m["validation"]["stages"].as_array().unwrap().iter().map(|s| s["stage"].as_str().unwrap()).collect();
    assert_eq!(stages, ["I", "II"]);
    assert!(!sure.join("reflection.ply").exists());
    check_validation(ctx);
}
