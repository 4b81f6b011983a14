//! No command destroys user data, and corrupt or mismatched state is
//! refused by name: renders and evaluations never go into a dataset or over
//! files tgs did not write; damaged checkpoints, a changed dataset and a
//! checkpoint from another run are refused on resume; a checkpoint from an
//! earlier tgs names the settings it lacks; sweep rows are keyed by their
//! complete settings and the dataset.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use tgs::outdir::{OutDir, MANIFEST};
use tgs::sweep::{sweep, SweepArgs};
use tgs::train::checkpoint;
use tgs::train::run::{open_run, train, TrainArgs};
use tgs_tests::{check_validation, ctx_shared};

/// The driver's stop flag is process-wide: one driver run at a time.
static DRIVER: Mutex<()> = Mutex::new(());

/// A private copy of the tiny glass scene (tests here change datasets).
fn own_scene(base: &Path) -> PathBuf {
    let shared = tgs_tests::tiny_glass_scene(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("reliability-scene"));
    let dir = base.join("dataset");
    tgs_tests::copy_dir(&shared, &dir);
    dir
}

/// Every file under `dir` with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            out.extend(snapshot(&p));
        } else {
            out.insert(p.clone(), std::fs::read(&p).unwrap());
        }
    }
    out
}

/// A scratch directory `name` with a private dataset and, in `run`, a
/// 12-iteration Stage I run trained on it (call with the DRIVER lock held).
fn trained_run(name: &str) -> (tgs_tests::TempDir, PathBuf, PathBuf) {
    let base = tgs_tests::TempDir::created(name);
    let ds = own_scene(&base);
    let run = base.join("run");
    train(ctx_shared(), &tiny_args(&ds, &run, 12)).unwrap();
    (base, ds, run)
}

/// A 12-iteration Stage I run with a checkpoint.
fn tiny_args(dataset: &Path, out: &Path, iterations: u32) -> TrainArgs {
    let set = ["stages=\"I\"", "background=\"black\"", "test_interval=0", "checkpoint_interval=0", "densify_from=1000"];
    TrainArgs {
        dataset: Some(dataset.to_path_buf()),
        out: out.to_path_buf(),
        iterations: Some(iterations),
        set: set.iter().map(|s| s.to_string()).collect(),
        quiet: true,
        ..Default::default()
    }
}

fn err<T>(r: anyhow::Result<T>) -> String {
    match r {
        Ok(_) => panic!("expected an error"),
        Err(e) => format!("{e:#}"),
    }
}

#[test]
fn renders_never_go_into_a_dataset_or_over_other_files() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = ctx_shared();
    let (base, ds, run) = trained_run("reliability-out");
    let before = snapshot(&ds);

    // Into the dataset, its split directories or the dataset itself: refused with the path.
    for (cams, out) in [("train", ds.join("train")), ("test", ds.join("test")), ("test", ds.clone()), ("train", ds.join("new/deeper"))] {
        let e = err(tgs::render::render(ctx, &run, cams, 1, &out));
        assert!(e.contains("never writes into a dataset") && e.contains(&*out.to_string_lossy()), "{e}");
    }
    // eval --out into the dataset, through the same door.
    let (mut tr, data) = open_run(ctx, &run).unwrap();
    let e = err(OutDir::open(&ds.join("test"), Some(&data.root)));
    assert!(e.contains("never writes into a dataset"), "{e}");
    // A dataset that is not the run's is recognised by its transforms.
    let other = base.join("other-dataset");
    tgs_tests::copy_dir(&ds, &other);
    let e = err(tgs::render::render(ctx, &run, "test", 1, &other.join("test")));
    assert!(e.contains("never writes into a dataset"), "{e}");
    // Training into a dataset is refused before anything is written.
    let e = err(train(ctx, &tiny_args(&ds, &ds.join("run"), 12)));
    assert!(e.contains("never writes into a dataset"), "{e}");
    assert!(!ds.join("run").exists());
    assert_eq!(snapshot(&ds), before, "the dataset was changed");

    // A directory holding a file of an output's name that tgs did not write.
    let mine = base.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    let name = &data.test[0].name;
    std::fs::write(mine.join(format!("{name}_depth.png")), b"my own file").unwrap();
    let e = err(tgs::eval::evaluate(&mut tr, &data.test, Some(&mut OutDir::open(&mine, Some(&data.root)).unwrap())));
    assert!(e.contains(&format!("{name}_depth.png")) && e.contains("not written by tgs"), "{e}");
    assert_eq!(std::fs::read(mine.join(format!("{name}_depth.png"))).unwrap(), b"my own file");
    // A new directory: written, listed, and written again (tgs's own files).
    let fresh = base.join("fresh");
    let n = tgs::render::render(ctx, &run, "test", 1, &fresh).unwrap();
    assert_eq!(n, data.test.len());
    let listed = std::fs::read_to_string(fresh.join(MANIFEST)).unwrap();
    assert!(listed.lines().any(|l| l == format!("{name}.png")), "{listed}");
    tgs::render::render(ctx, &run, "test", 1, &fresh).unwrap();
    // A training run's own test renders are tgs's: `tgs render RUN` may replace them.
    let o = train(ctx, &TrainArgs { iterations: Some(2), ..tiny_args(&ds, &base.join("run2"), 2) }).unwrap();
    assert!(o.metrics.is_some());
    tgs::render::render(ctx, &base.join("run2"), "test", 1, &base.join("run2/renders/test")).unwrap();
    // A new run in a directory that holds a file of a run's names that tgs did not write.
    let foreign = base.join("foreign");
    std::fs::create_dir_all(&foreign).unwrap();
    std::fs::write(foreign.join("metrics.json"), b"{}").unwrap();
    let e = err(train(ctx, &tiny_args(&ds, &foreign, 2)));
    assert!(e.contains("metrics.json") && e.contains("not written by tgs"), "{e}");
    assert_eq!(std::fs::read(foreign.join("metrics.json")).unwrap(), b"{}");
    check_validation(ctx);
}

/// Byte offsets of every array in a version-2 checkpoint (after the
/// magic, the header and its checksum), with the arrays' names.
fn array_offsets(bytes: &[u8]) -> Vec<(String, usize, usize)> {
    let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let h: checkpoint::Header = serde_json::from_slice(&bytes[12..12 + hlen]).unwrap();
    let mut at = 12 + hlen + 4;
    let mut out = Vec::new();
    let later = h.later_arrays().unwrap();
    for (name, len) in h.arrays.iter().chain(&later) {
        out.push((name.clone(), at, 4 * len));
        at += 4 * len + 4;
    }
    assert_eq!(at, bytes.len());
    out
}

#[test]
fn damaged_checkpoints_are_refused_naming_the_part() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = ctx_shared();
    let (base, ds, run) = trained_run("reliability-ckpt");
    let ck = run.join("checkpoint.bin");
    let good = std::fs::read(&ck).unwrap();
    assert_eq!(&good[..8], b"TGSCKPT2");
    checkpoint::read(&ck).unwrap();
    let damaged = base.join("damaged.bin");
    let read_with = |bytes: &[u8]| {
        std::fs::write(&damaged, bytes).unwrap();
        checkpoint::read(&damaged).map(|_| ())
    };
    // One flipped bit in the header.
    let mut b = good.clone();
    b[20] ^= 0x01;
    let e = err(read_with(&b));
    assert!(e.contains("damaged.bin") && (e.contains("header") || e.contains("corrupt")), "{e}");
    // An exponent bit of one value in each array: refused, naming the array.
    let arrays = array_offsets(&good);
    assert!(arrays.len() >= 5);
    for (name, at, len) in &arrays {
        if *len == 0 {
            continue;
        }
        let mut b = good.clone();
        b[at + len / 2 / 4 * 4 + 3] ^= 0x40;
        let e = err(read_with(&b));
        assert!(e.contains(&format!("array {name}'s checksum")), "{name}: {e}");
    }
    // Random 8-byte corruptions anywhere: every one refused.
    let mut rng = tgs_tests::Rng(tgs_tests::seed("damaged_checkpoints"));
    for _ in 0..32 {
        let at = rng.below(good.len() as u32 - 8) as usize;
        let mut b = good.clone();
        let mut changed = false;
        for k in 0..8 {
            let v = rng.next_u32() as u8;
            changed |= b[at + k] != v;
            b[at + k] = v;
        }
        if changed {
            let e = err(read_with(&b));
            assert!(e.contains("damaged.bin"), "corruption at {at}: {e}");
        }
    }
    // The trailing checksum of the last array cut off.
    assert!(err(read_with(&good[..good.len() - 2])).contains("damaged.bin"));
    // Resuming from a damaged checkpoint: refused with exit, nothing trained.
    let mut b = good.clone();
    let (_, at, _) = &arrays[0];
    b[*at] ^= 0x10;
    std::fs::write(&ck, &b).unwrap();
    let e = err(train(ctx, &TrainArgs { resume: true, dataset: None, set: Vec::new(), ..tiny_args(&ds, &run, 20) }));
    assert!(e.contains(&format!("array {}'s checksum", arrays[0].0)), "{e}");
    check_validation(ctx);
}

#[test]
fn resume_refuses_a_changed_dataset_and_another_runs_checkpoint() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = ctx_shared();
    let (base, ds, run) = trained_run("reliability-resume");
    let resume = || train(ctx, &TrainArgs { resume: true, dataset: None, set: Vec::new(), ..tiny_args(&ds, &run, 14) });

    // One training image replaced (a pixel changed): refused, naming it.
    let img = ds.join("train/r_1.png");
    let original = std::fs::read(&img).unwrap();
    let mut im = image::open(&img).unwrap().to_rgba8();
    let p = im.get_pixel_mut(3, 3);
    p.0[0] = p.0[0].wrapping_add(40);
    im.save(&img).unwrap();
    let e = err(resume());
    assert!(e.contains("changed") && e.contains("train/r_1.png"), "{e}");
    // So are eval and render, which read the same checkpoint.
    assert!(err(open_run(ctx, &run)).contains("train/r_1.png"));
    std::fs::write(&img, &original).unwrap();

    // The frames cut to the first two.
    let tf = ds.join("transforms_train.json");
    let text = std::fs::read_to_string(&tf).unwrap();
    let mut doc: serde_json::Value = serde_json::from_str(&text).unwrap();
    doc["frames"].as_array_mut().unwrap().truncate(2);
    std::fs::write(&tf, serde_json::to_string(&doc).unwrap()).unwrap();
    let e = err(resume());
    assert!(e.contains("transforms_train.json") && e.contains("no longer used"), "{e}");
    std::fs::write(&tf, &text).unwrap();
    // Restored: it resumes.
    assert_eq!(resume().unwrap().iteration, 14);

    // Another run's checkpoint copied in: refused, naming both runs.
    let other = base.join("other");
    train(ctx, &tiny_args(&ds, &other, 12)).unwrap();
    std::fs::copy(other.join("checkpoint.bin"), run.join("checkpoint.bin")).unwrap();
    let log_before = std::fs::read(run.join("log.jsonl")).unwrap();
    let e = err(resume());
    assert!(e.contains("belongs to another run"), "{e}");
    assert_eq!(std::fs::read(run.join("log.jsonl")).unwrap(), log_before, "the log was touched");
    check_validation(ctx);
}

/// A checkpoint whose header lacks a setting of this version (written by
/// an earlier tgs) names it, with the default it now takes, and still
/// resumes; this version's own checkpoints lack none.
#[test]
fn a_checkpoint_from_an_earlier_tgs_names_the_settings_it_lacks() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let ctx = ctx_shared();
    let (_base, ds, run) = trained_run("reliability-old-settings");
    let ck = run.join("checkpoint.bin");
    let (h, _) = checkpoint::read(&ck).unwrap();
    assert!(h.missing_settings.is_empty(), "{:?}", h.missing_settings);
    assert!(checkpoint::missing_settings_note(&ck, &h, &h.config).unwrap().is_none());
    // The header rewritten without two settings (one of a section, one
    // top-level), its length and checksum made right again.
    let old = tgs_tests::edit_checkpoint_header(&std::fs::read(&ck).unwrap(), |h| {
        assert!(h["config"]["reflection"].as_object_mut().unwrap().remove("dataset_masks").is_some());
        assert!(h["config"].as_object_mut().unwrap().remove("lambda_dist").is_some());
    });
    std::fs::write(&ck, &old).unwrap();
    let (h, _) = checkpoint::read(&ck).unwrap();
    let mut missing = h.missing_settings.clone();
    missing.sort();
    assert_eq!(missing, ["lambda_dist", "reflection.dataset_masks"]);
    let note = checkpoint::missing_settings_note(&ck, &h, &h.config).unwrap().unwrap();
    assert!(note.contains("checkpoint.bin") && note.contains("reflection.dataset_masks = true") && note.contains("lambda_dist = 0"), "{note}");
    // It resumes, on this version's defaults.
    assert_eq!(train(ctx, &TrainArgs { resume: true, dataset: None, set: Vec::new(), ..tiny_args(&ds, &run, 14) }).unwrap().iteration, 14);
    check_validation(ctx);
}

#[test]
fn sweep_rows_follow_the_settings_and_the_dataset() {
    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let base = tgs_tests::TempDir::created("reliability-sweep");
    let ds = own_scene(&base);
    let grid = |iters: u32| {
        let g = base.join("grid.toml");
        std::fs::write(&g, format!("[base]\nstages = \"I\"\niterations = {iters}\ntest_interval = 0\ncheckpoint_interval = 0\n[knobs]\nsh_degree = [1]\n")).unwrap();
        g
    };
    let a = |g: PathBuf| SweepArgs { dataset: Some(ds.clone()), out: base.join("sweep"), grid: Some(g), quiet: true };
    let first = sweep(ctx_shared(), &a(grid(6))).unwrap();
    assert_eq!(first.trained, 2);
    // The same grid: nothing trained.
    assert_eq!(sweep(ctx_shared(), &a(grid(6))).unwrap().trained, 0);
    // The base changed: the rows of the same names are stale and trained again.
    let changed = sweep(ctx_shared(), &a(grid(8))).unwrap();
    assert_eq!(changed.trained, 2);
    assert!(changed.rows.iter().all(|r| r.iterations == 8), "{:?}", changed.rows);
    // The dataset changed (one test image): trained again.
    let img = ds.join("test/r_0.png");
    let mut im = image::open(&img).unwrap().to_rgba8();
    im.get_pixel_mut(0, 0).0[1] ^= 0x55;
    im.save(&img).unwrap();
    assert_eq!(sweep(ctx_shared(), &a(grid(8))).unwrap().trained, 2);
    check_validation(ctx_shared());
}

/// Views named with their image's extension (COLMAP's `0000.jpg`, a
/// Blender `file_path` ending in `.png`) write `NAME.png`, not
/// `NAME.png.png`, unless two views would then share a file; glass masks
/// named the old way are still read.
#[test]
fn files_per_view_drop_the_image_extension() {
    let names = ["0000.jpg", "IMG_1.JPG", "r_0", "a.b.png", "x.png", "x.jpg", "dir/y.exr", ".png", "dir/.png"];
    assert_eq!(tgs::data::file_stems(names), ["0000", "IMG_1", "r_0", "a.b", "x.png", "x.jpg", "dir/y", ".png", "dir/.png"]);

    let _guard = DRIVER.lock().unwrap_or_else(|e| e.into_inner());
    let base = tgs_tests::TempDir::created("reliability-stems");
    let ds = own_scene(&base);
    let path = ds.join("transforms_test.json");
    let mut t: serde_json::Value = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    for f in t["frames"].as_array_mut().unwrap() {
        f["file_path"] = format!("{}.png", f["file_path"].as_str().unwrap()).into();
    }
    std::fs::write(&path, serde_json::to_vec(&t).unwrap()).unwrap();
    let run = base.join("run");
    train(ctx_shared(), &tiny_args(&ds, &run, 2)).unwrap();
    let renders = run.join("renders/test");
    assert!(renders.join("r_0.png").is_file() && renders.join("r_0_normal.png").is_file(), "renders/test/r_0.png");
    assert!(!renders.join("r_0.png.png").exists(), "renders/test/r_0.png.png written");

    // reflection.seed_masks: DIR/r_0.png, or the old DIR/r_0.png.png.
    let cam = tgs_pipelines::Camera::look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 0.8, 4, 3);
    let masks = base.join("masks");
    std::fs::create_dir_all(&masks).unwrap();
    image::save_buffer(masks.join("r_1.png.png"), &[255u8; 12], 4, 3, image::ExtendedColorType::L8).unwrap();
    let got = tgs::train::stages::reflection::stage::seed_masks(&masks, &["r_0.png".into(), "r_1.png".into()], &[cam, cam], 1).unwrap();
    assert_eq!(got, [None, Some(vec![true; 12])]);
    check_validation(ctx_shared());
}
