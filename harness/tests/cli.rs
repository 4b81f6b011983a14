//! The `tgs` command line as a user types it: options that were ignored or
//! accepted with nonsense values before are honoured or refused with a
//! message, before any work or allocation; and the third round of hostile
//! but realistic use (issue 80): two writers on one run directory, a
//! diverging run, a sweep told to stop, and inputs that were accepted, hung
//! or read without end before. Every case failed before its fix.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn tgs() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_tgs"));
    c.env_remove("TGS_DEVICE");
    c
}

fn run(args: &[&str]) -> Output {
    tgs().args(args).output().expect("running tgs")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Fails (not by a signal or a panic) with a message holding every needle.
fn refused(args: &[&str], needles: &[&str]) -> String {
    let o = run(args);
    let t = text(&o);
    assert!(!o.status.success(), "tgs {args:?} should fail:\n{t}");
    assert!(o.status.code().is_some(), "tgs {args:?} ended by a signal:\n{t}");
    for n in needles {
        assert!(t.contains(n), "tgs {args:?}: '{n}' missing from:\n{t}");
    }
    assert!(!t.contains("panicked") && !t.contains("memory allocation"), "tgs {args:?}:\n{t}");
    t
}

/// Succeeds; its output.
fn ok(args: &[&str]) -> String {
    let o = run(args);
    let t = text(&o);
    assert!(o.status.success(), "tgs {args:?} failed:\n{t}");
    t
}

/// A scratch directory removed when dropped.
struct Scratch(PathBuf);

impl Scratch {
    fn new(name: &str) -> Scratch {
        let d = std::env::temp_dir().join(format!("tgs-hostile-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        Scratch(d)
    }
    fn join(&self, p: &str) -> PathBuf {
        self.0.join(p)
    }
    fn s(&self, p: &str) -> String {
        self.join(p).to_string_lossy().into_owned()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The built-in tiny glass scene (48x48, 16 + 4 views) written to `dir`.
fn scene(dir: &Path) -> String {
    tgs::scene::make(&tgs::scene::spec("glass-tiny").unwrap(), dir, |_, _| {}).unwrap();
    dir.to_string_lossy().into_owned()
}

/// Rewrite `file`'s JSON with `edit`.
fn edit_json(file: &Path, edit: impl FnOnce(&mut serde_json::Value)) {
    let mut v: serde_json::Value = serde_json::from_slice(&std::fs::read(file).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(file, serde_json::to_vec_pretty(&v).unwrap()).unwrap();
}

/// Wait for `child` up to `limit`; kill it and fail past that.
fn wait_within(mut child: Child, limit: Duration, what: &str) -> (std::process::ExitStatus, Duration) {
    let start = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return (s, start.elapsed());
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            panic!("{what}: still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn render_frames_are_bounded() {
    // Before: --frames 0 rendered one frame, 4294967295 aborted allocating 309 GB.
    refused(&["render", "no-such-run", "--cameras", "orbit", "--frames", "0"], &["--frames", "0"]);
    refused(&["render", "no-such-run", "--cameras", "orbit", "--frames", "4294967295"], &["--frames"]);
}

#[test]
fn sweep_print_grid_needs_no_out() {
    let o = run(&["sweep", "--print-grid"]);
    assert!(o.status.success(), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stdout).contains("[knobs]"));
    refused(&["sweep"], &["--out"]);
}

#[test]
fn devices_honours_device() {
    let all = run(&["devices", "--json"]);
    assert!(all.status.success(), "{}", text(&all));
    let list: serde_json::Value = serde_json::from_slice(&all.stdout).unwrap();
    let n = list.as_array().unwrap().len();
    refused(&["devices", "--device", "7"], &["--device 7", "no such Vulkan device"]);
    refused(&["devices", "--device", "no-such-gpu-name"], &["no-such-gpu-name"]);
    if n > 0 {
        let one = run(&["devices", "--json", "--device", "0"]);
        let v: serde_json::Value = serde_json::from_slice(&one.stdout).unwrap();
        assert_eq!(v.as_array().unwrap().len(), 1);
        assert_eq!(v[0]["index"], 0);
    }
}

#[test]
fn benches_refuse_sizes_that_cannot_run() {
    // Before: 19 GB of host memory and no output; an error after 45 s; -inf and NaN rates.
    refused(&["bench", "raster", "--n", "2147483648"], &["--n 2147483648", "MiB"]);
    refused(&["bench", "sort", "--n", "4294967295"], &["--n 4294967295"]);
    refused(&["bench", "sort", "--reps", "0"], &["--reps"]);
    refused(&["bench", "scan", "--reps", "0"], &["--reps"]);
    refused(&["bench", "mlp", "--n", "0"], &["--n 0"]);
    refused(&["bench", "mlp", "--reps", "0", "--preset", "small"], &["--reps"]);
    refused(&["bench", "train", "--light-field", "large"], &["--light-field", "large"]);
    refused(&["bench", "train", "--light-field", "small", "--from", "run"], &["--light-field"]);
    refused(&["bench", "raster", "--width", "0"], &["--width"]);
}

const STAGE_I: [&str; 6] = ["--stages", "I", "--set", "test_interval=0", "--set", "checkpoint_interval=0"];

#[test]
fn one_writer_per_run_directory() {
    let base = Scratch::new("lock");
    let ds = scene(&base.join("ds"));
    let out = base.s("run");
    // A long first writer; the second (other settings) is refused at once, naming it.
    let first = tgs().args(["train", &ds, "--out", &out, "--iterations", "100000", "--quiet"]).args(STAGE_I).stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
    let lock = base.join("run/.tgs-lock");
    let start = Instant::now();
    while std::fs::read_to_string(&lock).map(|s| s.is_empty()).unwrap_or(true) {
        assert!(start.elapsed() < Duration::from_secs(60), "the first writer never took its lock");
        std::thread::sleep(Duration::from_millis(20));
    }
    let pid = first.id().to_string();
    let t0 = Instant::now();
    refused(&["train", &ds, "--out", &out, "--iterations", "10", "--set", "lambda_ssim=0.1"], &["in use by tgs train", &format!("PID {pid}"), "run"]);
    refused(&["train", "--out", &out, "--resume"], &["in use by tgs train", &format!("PID {pid}")]);
    assert!(t0.elapsed() < Duration::from_secs(30), "refusals took {:?}", t0.elapsed());
    // Killed without a chance to release: the next writer takes the lock over and says so.
    let mut first = first;
    first.kill().unwrap();
    first.wait().unwrap();
    assert!(std::fs::read_to_string(&lock).unwrap().contains(&format!("PID {pid}")));
    let t = ok(&["train", &ds, "--out", &out, "--iterations", "10", "--stages", "I"]);
    assert!(t.contains(&format!("taking over the lock of tgs train (PID {pid}")), "{t}");
    // Released cleanly: the lock file is left empty.
    assert_eq!(std::fs::read_to_string(&lock).unwrap(), "");

    // In one process: a second lock on a held directory is refused.
    let held = tgs::lock::lock_dir(&base.0, "test", true).unwrap();
    let e = format!("{:#}", tgs::lock::lock_dir(&base.0, "another", true).unwrap_err());
    assert!(e.contains("in use by test (PID") && e.contains(&std::process::id().to_string()), "{e}");
    drop(held);
    tgs::lock::lock_dir(&base.0, "again", true).unwrap();
}

#[test]
fn divergence_stops_at_once_with_the_cause() {
    let base = Scratch::new("diverge");
    let ds = scene(&base.join("ds"));
    std::fs::remove_file(base.join("ds/points3d.ply")).unwrap();
    let out = base.s("run");
    // Random initial points in a cube of 1e30: positions past 1e6 scene extents at iteration 1.
    let t = refused(
        &["train", &ds, "--out", &out, "--iterations", "200", "--set", "init_half_extent=1e30"],
        &["iteration 1:", "diverged", "means", "likely cause: init_half_extent = 1e30", "checkpoint-nonfinite.bin"],
    );
    assert!(!t.contains("iteration 2:"), "{t}");
    assert!(base.join("run/checkpoint-nonfinite.bin").is_file() && !base.join("run/point_cloud.ply").exists() && !base.join("run/metrics.json").exists());
    // Rates beyond any sane bound are refused before training; high ones warned about.
    refused(&["train", &ds, "--out", &base.s("lr"), "--set", "lr_means=1e30"], &["lr_means = 1e30", "learning rate"]);
    refused(&["train", &ds, "--out", &base.s("lr"), "--set", "light_field.lr=5000"], &["light_field.lr = 5e3"]);
    assert!(!base.join("lr/checkpoint.bin").exists());
    let t = ok(&["train", &ds, "--out", &base.s("warn"), "--iterations", "2", "--stages", "I", "--set", "lr_opacity=10"]);
    assert!(t.contains("warning: lr_opacity = 10") && t.contains("100x or more"), "{t}");
    // A camera far outside the others (a translation of 1e30) is refused by name at load.
    edit_json(&base.join("ds/transforms_train.json"), |v| v["frames"][3]["transform_matrix"][0][3] = serde_json::json!(1e30));
    refused(&["train", &ds, "--out", &base.s("cam")], &["view 'r_3'", "median distance", "corrupt transform"]);
}

#[test]
fn a_sweep_stops_on_sigterm_with_its_csv_whole() {
    let base = Scratch::new("sweep");
    let ds = scene(&base.join("ds"));
    let grid = base.join("grid.toml");
    let values: Vec<String> = (2..=60).map(|i| i.to_string()).collect();
    std::fs::write(&grid, format!("mode = \"one_at_a_time\"\n[base]\niterations = 1\nstages = \"I\"\ntest_interval = 0\n[knobs]\niterations = [{}]\n", values.join(", "))).unwrap();
    let out = base.s("sweep");
    let child = tgs().args(["sweep", &ds, "--out", &out, "--grid", &grid.to_string_lossy(), "--quiet"]).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let csv = base.join("sweep/sweep.csv");
    let start = Instant::now();
    while !csv.is_file() {
        assert!(start.elapsed() < Duration::from_secs(120), "no run finished");
        std::thread::sleep(Duration::from_millis(20));
    }
    // One signal, as `timeout` and SLURM send.
    assert!(Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap().success());
    let (status, took) = wait_within(child, Duration::from_secs(30), "the sweep after SIGTERM");
    assert!(took < Duration::from_secs(10), "the sweep took {took:?} to stop");
    assert_eq!(status.code(), Some(130), "{status:?}");
    let text = std::fs::read_to_string(&csv).unwrap();
    let lines: Vec<&str> = text.lines().collect();
    assert!(lines.len() >= 2 && lines.len() < 1 + values.len(), "{} lines", lines.len());
    assert!(lines.iter().all(|l| l.split(',').count() == lines[0].split(',').count()), "{text}");
}

#[test]
fn inputs_are_checked_before_any_work() {
    let base = Scratch::new("inputs");
    let ds = scene(&base.join("ds"));
    // Random initialisation: init_points is what is made.
    std::fs::remove_file(base.join("ds/points3d.ply")).unwrap();
    let out = base.s("run");
    // Settings files read without end: refused as what they are.
    refused(&["train", &ds, "--out", &out, "--config", "/dev/zero"], &["/dev/zero", "not a regular file"]);
    refused(&["sweep", &ds, "--out", &out, "--grid", "/dev/zero"], &["/dev/zero", "not a regular file"]);
    std::fs::write(base.join("big.toml"), vec![b'#'; 2 << 20]).unwrap();
    refused(&["train", &ds, "--out", &out, "--config", &base.s("big.toml")], &["big.toml", "KiB"]);
    // Sizes against memory before allocating.
    refused(&["train", &ds, "--out", &out, "--set", "init_points=200000000"], &["init_points 200000000", "max_gaussians"]);
    refused(&["train", &ds, "--out", &out, "--set", "init_points=2000000000", "--set", "max_gaussians=2000000000"], &["init_points", "GiB of device memory"]);
    // A grid of a million runs: refused at once with its size.
    std::fs::write(
        base.join("huge.toml"),
        format!(
            "mode = \"product\"\n[knobs]\niterations = [{}]\nsh_degree = [0, 1, 2, 3]\nlambda_ssim = [{}]\n",
            (1..=500).map(|i| i.to_string()).collect::<Vec<_>>().join(","),
            (0..=500).map(|i| format!("{}", i as f64 / 500.0)).collect::<Vec<_>>().join(",")
        ),
    )
    .unwrap();
    let t0 = Instant::now();
    refused(&["sweep", &ds, "--out", &base.s("huge"), "--grid", &base.s("huge.toml")], &["1002000 runs", "at most 10000"]);
    assert!(t0.elapsed() < Duration::from_secs(10));
    // A path the later stages read is resolved before Stage I trains.
    let t0 = Instant::now();
    refused(&["train", &ds, "--out", &out, "--set", "reflection.seed_masks=/nonexistent"], &["reflection.seed_masks", "/nonexistent", "checked before training"]);
    assert!(!base.join("run/checkpoint.bin").exists() && t0.elapsed() < Duration::from_secs(30));
    // System folders are no place for a run.
    refused(&["train", &ds, "--out", "/"], &["system folder"]);
    refused(&["train", &ds, "--out", "/etc/tgs-run"], &["system folder"]);
    refused(&["bench", "train", "--res", "0"], &["--res 0"]);
    assert!(!text(&run(&["bench", "train", "--res", "0"])).contains("SpheresSpec {"));
    // mesh --voxel larger than the scene: refused, not an empty mesh.
    ok(&["train", &ds, "--out", &out, "--iterations", "20", "--stages", "I", "--quiet"]);
    refused(&["mesh", &out, "--voxel", "1e30"], &["--voxel 1e30", "empty"]);
    assert!(!base.join("run/mesh_scene.ply").exists());
}

/// A copy of the scene whose first training frame is edited.
fn variant(base: &Scratch, name: &str, edit: impl FnOnce(&Path, &mut serde_json::Value)) -> String {
    let ds = base.join(name);
    scene(&ds);
    edit_json(&ds.join("transforms_train.json"), |v| edit(&ds, v));
    ds.to_string_lossy().into_owned()
}

#[test]
fn datasets_that_were_read_wrong_are_refused_or_said() {
    let base = Scratch::new("data");
    let out = base.s("run");
    // A truncated JPEG (a complete one, with a camera's trailer after it, loads).
    let ds = variant(&base, "jpeg", |d, v| {
        let img = image::open(d.join("train/r_0.png")).unwrap().to_rgb8();
        let mut whole = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut whole, 95).encode_image(&img).unwrap();
        assert!(tgs::data::image_io::jpeg_complete(&whole).is_ok());
        std::fs::write(d.join("train/r_1.jpg"), [&whole[..], b"TRAILER"].concat()).unwrap();
        std::fs::write(d.join("train/r_0.jpg"), &whole[..whole.len() * 2 / 3]).unwrap();
        v["frames"][0]["file_path"] = "./train/r_0.jpg".into();
        v["frames"][1]["file_path"] = "./train/r_1.jpg".into();
    });
    refused(&["train", &ds, "--out", &out], &["r_0.jpg", "truncated"]);
    // Intrinsics written for another image size.
    let ds = variant(&base, "size", |_, v| {
        v["w"] = 96.into();
        v["h"] = 96.into();
    });
    refused(&["train", &ds, "--out", &out], &["w = 96, h = 96", "48x48"]);
    let ds = variant(&base, "cx", |_, v| v["cx"] = 96.0.into());
    refused(&["train", &ds, "--out", &out], &["cx = 96", "outside the 48x48 image"]);
    let ds = variant(&base, "frame-w", |_, v| v["frames"][2]["w"] = 24.into());
    refused(&["train", &ds, "--out", &out], &["frame 2", "w = 24"]);
    // An empty file_path names no file (it read <dataset>.png beside the dataset).
    let ds = variant(&base, "empty-path", |_, v| v["frames"][0]["file_path"] = "".into());
    std::fs::write(base.join("empty-path.png"), b"outside").unwrap();
    refused(&["train", &ds, "--out", &out], &["file path ''", "names no file"]);
    // A FIFO in place of an image is refused, not waited on.
    let ds = variant(&base, "fifo", |d, _| {
        std::fs::remove_file(d.join("train/r_0.png")).unwrap();
        assert!(Command::new("mkfifo").arg(d.join("train/r_0.png")).status().unwrap().success());
    });
    let child = tgs().args(["train", &ds, "--out", &out]).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let (status, _) = wait_within(child, Duration::from_secs(30), "a FIFO as an image");
    assert!(!status.success());
    refused(&["train", &ds, "--out", &out], &["r_0.png", "not a regular file"]);
    // A damaged PNG's message is said once.
    let ds = variant(&base, "crc", |d, _| {
        let mut b = std::fs::read(d.join("train/r_0.png")).unwrap();
        b[20] ^= 0xff;
        std::fs::write(d.join("train/r_0.png"), b).unwrap();
    });
    let t = refused(&["train", &ds, "--out", &out], &["r_0.png", "CRC error"]);
    assert_eq!(t.matches("CRC error").count(), 1, "{t}");
    // A byte-order mark before the JSON is read past.
    let ds = variant(&base, "bom", |_, _| {});
    let f = base.join("bom/transforms_train.json");
    std::fs::write(&f, [&b"\xEF\xBB\xBF"[..], &std::fs::read(&f).unwrap()].concat()).unwrap();
    let t = ok(&["train", &ds, "--out", &base.s("bom-run"), "--iterations", "2", "--stages", "I"]);
    assert!(t.contains("done: 2 iterations"), "{t}");
    // Silent fallbacks are said: no test split, an empty point cloud.
    let ds = variant(&base, "no-test", |d, _| std::fs::remove_file(d.join("transforms_test.json")).unwrap());
    let ply = "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";
    std::fs::write(base.join("no-test/points3d.ply"), ply).unwrap();
    let t = ok(&["train", &ds, "--out", &base.s("no-test-run"), "--iterations", "2", "--stages", "I"]);
    assert!(t.contains("no transforms_test.json") && t.contains("no test metrics"), "{t}");
    assert!(t.contains("points3d.ply: it holds no usable point") && t.contains("init_points random points"), "{t}");
}

#[test]
fn a_stage_resumed_inside_is_logged_as_begun_once() {
    let base = Scratch::new("begin");
    let ds = scene(&base.join("ds"));
    let out = base.s("run");
    ok(&["train", &ds, "--out", &out, "--iterations", "30", "--stages", "I,II", "--set", "reflection.iterations=10", "--set", "test_interval=0", "--quiet"]);
    // Continued inside Stage II (it gets longer), which begins it again to rebuild its cache.
    ok(&["train", "--out", &out, "--resume", "--set", "reflection.iterations=20", "--quiet"]);
    let log = std::fs::read_to_string(base.join("run/log.jsonl")).unwrap();
    let begins: Vec<&str> = log.lines().filter(|l| l.contains("\"event\":\"begin\"")).collect();
    assert_eq!(begins.len(), 1, "{begins:?}");
    assert!(log.lines().last().unwrap().contains("\"iteration\":50"));
}
