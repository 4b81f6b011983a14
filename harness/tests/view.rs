//! `tgs view` under a virtual display (xvfb-run, lavapipe): a scripted
//! camera path and key presses, frames captured from the swapchain and
//! compared with `tgs render` for the same cameras; layer and checkpoint
//! keys change what they should; the window survives a resize to 1x1 and
//! back; missing or corrupt runs and a missing display get clear errors.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn tgs() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_tgs"));
    c.env_remove("TGS_DEVICE");
    c
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn ok(c: &mut Command) -> String {
    let o = c.output().expect("running tgs");
    let t = text(&o);
    assert!(o.status.success(), "{c:?} failed:\n{t}");
    t
}

/// `tgs view` with `args` under xvfb-run (scripts/setup.sh installs it).
fn view(args: &[&str]) -> Output {
    let mut c = Command::new("xvfb-run");
    c.args(["-a", "-s", "-screen 0 640x480x24", env!("CARGO_BIN_EXE_tgs"), "view"]).args(args).env_remove("TGS_DEVICE");
    c.output().expect("xvfb-run is missing: scripts/setup.sh installs it (package xvfb)")
}

fn rgb(p: &Path) -> image::RgbImage {
    image::open(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())).to_rgb8()
}

/// `tgs train` of a brief Stage I-II-III run of the tiny glass scene in `base/scene` into `run`.
fn train_args(base: &Path, run: &Path) -> Vec<String> {
    let mut a: Vec<String> =
        ["train", base.join("scene").to_str().unwrap(), "--out", run.to_str().unwrap(), "--preset", "quick", "--iterations", "150", "--quiet"].map(String::from).into();
    for s in ["test_interval=0", "checkpoint_interval=0", "reflection.iterations=40", "light_field.iterations=40"] {
        a.extend(["--set".to_string(), s.to_string()]);
    }
    a
}

/// A Stage I-II-III run of the tiny glass scene, trained briefly.
fn trained(base: &Path) -> PathBuf {
    tgs::scene::make(&tgs::scene::spec("glass-tiny").unwrap(), &base.join("scene"), |_, _| {}).unwrap();
    let run = base.join("run");
    ok(tgs().args(train_args(base, &run)));
    run
}

/// A checkpoint's arrays (everything after its header and the header's checksum).
fn checkpoint_arrays(run: &Path) -> Vec<u8> {
    let b = std::fs::read(run.join("checkpoint.bin")).unwrap();
    let n = u32::from_le_bytes(b[8..12].try_into().unwrap()) as usize;
    b[12 + n + 4..].to_vec()
}

#[test]
fn the_window_shows_what_tgs_render_writes() {
    let base = Path::new(env!("CARGO_TARGET_TMPDIR")).join("view");
    let _ = std::fs::remove_dir_all(&base);
    std::fs::create_dir_all(&base).unwrap();
    let run = trained(&base);
    let renders = base.join("renders");
    ok(tgs().args(["render", run.to_str().unwrap(), "--out", renders.to_str().unwrap()]));
    let script = base.join("path.txt");
    std::fs::write(
        &script,
        "capture shots/final0.png\n\
         key l\ncapture shots/gt0.png\n\
         key l\ncapture shots/normal0.png\n\
         key l\nkey l\ncapture shots/scat0.png\n\
         key k\nkey k\nkey k\nkey k\n\
         key n\ncapture shots/final1.png\n\
         orbit 60 15\nzoom 1\ncapture shots/orbit.png\n\
         key r\ncapture shots/again1.png\n\
         resize 1 1\nwait 3\ncapture shots/tiny.png\n\
         resize 48 48\nwait 3\ncapture shots/back1.png\n\
         key c\ncapture shots/stage1.png\n\
         key o\n",
    )
    .unwrap();
    let shots = base.join("own-shots");
    let o = view(&[run.to_str().unwrap(), "--size", "48x48", "--script", script.to_str().unwrap(), "--shots", shots.to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "tgs view failed:\n{t}");
    let shot = |n: &str| rgb(&base.join("shots").join(n));
    let render = |n: &str| rgb(&renders.join(n));
    // The swapchain's pixels are tgs render's, byte for byte, for the final image and a layer.
    assert_eq!(shot("final0.png"), render("r_0.png"), "camera 0, final");
    assert_eq!(shot("normal0.png"), render("r_0_normal.png"), "camera 0, normals");
    assert_eq!(shot("scat0.png"), render("r_0_scat.png"), "camera 0, scattering layer");
    assert_eq!(shot("final1.png"), render("r_1.png"), "camera 1, final");
    assert_eq!(shot("again1.png"), render("r_1.png"), "camera 1 after moving away and back (R)");
    assert_eq!(shot("back1.png"), render("r_1.png"), "camera 1 after a resize to 1x1 and back");
    // The photo layer is the dataset's test image, not a render.
    let gt = shot("gt0.png");
    assert_ne!(gt, shot("final0.png"));
    let photo = image::open(base.join("scene/test/r_0.png")).unwrap().to_rgb8();
    assert_eq!(gt, photo, "the gt layer shows the test photo");
    // Moving changes the image; 1x1 is one pixel; Stage I's checkpoint differs from Stage III's.
    assert_ne!(shot("orbit.png"), shot("final1.png"));
    assert_eq!(shot("tiny.png").dimensions(), (1, 1));
    assert_ne!(shot("stage1.png"), shot("back1.png"));
    // The screenshot key writes a new file, named for camera, layer and stage, into --shots.
    let own: Vec<_> = std::fs::read_dir(&shots).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    assert_eq!(own, vec!["r_1_final_stageI.png".to_string()], "{t}");
    assert_eq!(rgb(&shots.join(&own[0])), shot("stage1.png"));
    // A moving camera's frames drawn smaller (--motion-fps far above what
    // any frame makes: 1/4 while it moves); the capture after the motion is
    // full size, the same pixels as without.
    let moving = base.join("moving.txt");
    std::fs::write(&moving, "key n\norbit 60 15\nzoom 1\ncapture shots/orbit-small.png\n").unwrap();
    let o = view(&[run.to_str().unwrap(), "--size", "48x48", "--script", moving.to_str().unwrap(), "--motion-fps", "100000"]);
    assert!(o.status.success() && text(&o).contains("2 of them drawn at up to 1/4 size while moving"), "{}", text(&o));
    assert_eq!(shot("orbit-small.png"), shot("orbit.png"), "a capture after smaller frames");
    // Without a display the message names the headless way.
    let o = tgs().args(["view", run.to_str().unwrap()]).env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").output().unwrap();
    assert!(!o.status.success() && text(&o).contains("no display") && text(&o).contains("tgs render"), "{}", text(&o));
    // Run again: captures never write over a file.
    let o = view(&[run.to_str().unwrap(), "--size", "48x48", "--script", script.to_str().unwrap(), "--shots", shots.to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("final0.png: exists"), "{}", text(&o));

    // tgs train --view: the same training in a window. Its model arrives
    // while it trains; once trained the window shows what tgs render
    // writes of the finished run, and the checkpoint's arrays are those of
    // the run trained without a window.
    let live = base.join("live-run");
    std::fs::write(base.join("live.txt"), "resize 48 48\nwait 3\ncapture shots/live-early.png\ntrained\ncapture shots/live-final.png\n").unwrap();
    let mut c = Command::new("xvfb-run");
    c.args(["-a", "-s", "-screen 0 640x480x24", env!("CARGO_BIN_EXE_tgs")]).args(train_args(&base, &live)).args([
        "--view",
        "--view-script",
        base.join("live.txt").to_str().unwrap(),
    ]);
    let t = ok(&mut c);
    assert_eq!(checkpoint_arrays(&live), checkpoint_arrays(&run), "the window changed the training");
    // The training waited while the window drew each model (at least the first and the last).
    let sent = t.split("tgs train --view: ").nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse::<u32>().ok());
    assert!(sent.is_some_and(|n| n >= 2) && t.contains("the training waited"), "{t}");
    assert_eq!(shot("live-early.png").dimensions(), (48, 48));
    assert_eq!(shot("live-final.png"), render("r_0.png"), "the trained model in the window");
    marking_the_glass(&base, &run);
    std::fs::remove_dir_all(&base).unwrap();
}

/// The clicks a user makes around the glass in one view: the mask's
/// outermost pixel towards each of eight directions, as window
/// coordinates of their centres (the window is the camera's size).
fn outline_clicks(mask: &[bool], w: usize) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = (0..8)
        .map(|k| {
            let a = k as f64 * std::f64::consts::FRAC_PI_4;
            let i = (0..mask.len()).filter(|&i| mask[i]).max_by(|&i, &j| {
                let f = |i: usize| a.cos() * (i % w) as f64 + a.sin() * (i / w) as f64;
                f(i).total_cmp(&f(j))
            });
            let i = i.expect("a view with glass");
            ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5)
        })
        .collect();
    out.dedup();
    out
}

/// Marking the glass: eight clicks around it in two training views (key G,
/// scripted as a user's clicks), then masks for every training view in a
/// new directory, near the scene's exact masks; never over a directory.
fn marking_the_glass(base: &Path, run: &Path) {
    let opts = tgs::data::LoadOptions::default();
    let data = tgs::data::Dataset::load(&base.join("scene"), &opts).unwrap();
    let w = data.train[0].camera.width as usize;
    let mut script = String::from("key t\nkey g\n");
    for (k, view) in [0usize, 4].into_iter().enumerate() {
        if k > 0 {
            script += &"key n\n".repeat(4);
        }
        for (x, y) in outline_clicks(data.train[view].mask.as_ref().unwrap(), w) {
            script += &format!("click {x} {y}\n");
        }
    }
    script += "capture marked-view.png\nmarks marked\n";
    std::fs::write(base.join("marks.txt"), &script).unwrap();
    let o = view(&[run.to_str().unwrap(), "--size", "48x48", "--script", base.join("marks.txt").to_str().unwrap()]);
    let t = text(&o);
    assert!(o.status.success(), "tgs view failed:\n{t}");
    assert!(t.contains("reflection.seed_masks="), "{t}");
    let dir = base.join("marked");
    let record: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("marks.json")).unwrap()).unwrap();
    assert_eq!((record["tolerance"].as_u64(), record["regions"][0]["outlines"].as_array().map(Vec::len)), (Some(0), Some(2)), "{record}");
    let (mut both, mut either, mut truth_n, mut covered) = (0usize, 0usize, 0usize, 0usize);
    for v in &data.train {
        let stem = Path::new(&v.name).file_stem().unwrap().to_str().unwrap().to_string();
        let m = image::open(dir.join(format!("{stem}.png"))).unwrap().to_luma8();
        let truth = v.mask.as_ref().unwrap();
        for (p, &t) in m.pixels().zip(truth) {
            let marked = p.0[0] > 127;
            both += (marked && t) as usize;
            either += (marked || t) as usize;
            truth_n += t as usize;
            covered += (marked && t) as usize;
        }
    }
    // Marking shows the photo, the marked region tinted and the rest as it is.
    let shown = rgb(&base.join("marked-view.png"));
    let photo = image::open(base.join("scene/train/r_4.png")).unwrap().to_rgb8();
    let marked4 = image::open(dir.join("r_4.png")).unwrap().to_luma8();
    let (mut tinted, mut same) = (0, true);
    for ((s, p), m) in shown.pixels().zip(photo.pixels()).zip(marked4.pixels()) {
        if m.0[0] > 127 {
            tinted += (s != p) as usize;
        } else {
            same &= s == p;
        }
    }
    assert!(same && tinted > 20, "tinted {tinted}, unmarked pixels as the photo: {same}");
    let iou = both as f64 / either as f64;
    let recall = covered as f64 / truth_n as f64;
    eprintln!("marked glass against the exact masks, all {} training views: IoU {iou:.3}, recall {recall:.3}", data.train.len());
    assert!(iou > 0.6 && recall > 0.9, "IoU {iou}, recall {recall}");
    // Again into the same directory: refused, nothing written over.
    std::fs::remove_file(base.join("marked-view.png")).unwrap();
    let o = view(&[run.to_str().unwrap(), "--size", "48x48", "--script", base.join("marks.txt").to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("marked: exists"), "{}", text(&o));
}

#[test]
fn missing_or_corrupt_runs_and_no_display_are_said() {
    let base = Path::new(env!("CARGO_TARGET_TMPDIR")).join("view-errors");
    let _ = std::fs::remove_dir_all(&base);
    std::fs::create_dir_all(&base).unwrap();
    let missing = base.join("nothing");
    let o = tgs().args(["view", missing.to_str().unwrap()]).output().unwrap();
    assert!(!o.status.success() && text(&o).contains("nothing: no such run directory"), "{}", text(&o));
    let bad = base.join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("checkpoint.bin"), b"not a checkpoint at all").unwrap();
    let o = view(&[bad.to_str().unwrap()]);
    assert!(!o.status.success() && text(&o).contains("checkpoint.bin: not a tgs checkpoint or corrupt"), "{}", text(&o));
    let o = tgs().args(["view", bad.to_str().unwrap()]).env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").output().unwrap();
    assert!(!o.status.success() && text(&o).contains("corrupt"), "{}", text(&o));
    // A sound run without a display: the message names the headless way.
    let empty = base.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let o = tgs().args(["view", empty.to_str().unwrap()]).env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").output().unwrap();
    assert!(!o.status.success() && text(&o).contains("cannot read the checkpoint"), "{}", text(&o));
    std::fs::remove_dir_all(&base).unwrap();
}
