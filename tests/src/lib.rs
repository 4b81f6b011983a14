//! Helpers shared by the integration tests.

pub mod host;
pub mod lightfield_ref;
pub mod loss_ref;
pub mod lpips_ref;
pub mod mesh_checks;
pub mod mlp_ref;
pub mod raster_ref;
pub mod raster_util;
pub mod reflection_ref;
pub mod seed_scenes;
pub mod train_cases;
pub mod tsdf_ref;

use std::sync::Arc;
use tgs_engine::{Context, ContextOptions, DeviceSelector};

/// A context on the default device (or `TGS_DEVICE`) with validation layers
/// enabled when installed and `Buffer::uninit` memory poisoned (all bits set). Use [`check_validation`] at the end of a test.
pub fn ctx() -> Arc<Context> {
    let opts = ContextOptions { device: DeviceSelector::from_arg_or_env(None), validation: Some(validation_wanted()) };
    match Context::new(&opts) {
        Ok(c) => {
            // A kernel that reads memory nobody wrote then fails every run,
            // not only when an earlier test left the wrong bytes there.
            c.set_poison_uninit(true);
            c
        }
        Err(e) => panic!("no Vulkan device for tests: {e:#}"),
    }
}

/// Validation is on unless `TGS_VALIDATION=0`.
pub fn validation_wanted() -> bool {
    std::env::var("TGS_VALIDATION").map(|v| v != "0").unwrap_or(true)
}

/// Fail the test if the validation layer reported any error.
pub fn check_validation(ctx: &Context) {
    let errs = ctx.validation_errors();
    assert!(errs.is_empty(), "{} Vulkan validation error(s):\n{}", errs.len(), errs.join("\n"));
}

/// Small deterministic PRNG (SplitMix64) so failures can be reproduced from the seed.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        let mut r = tgs_pipelines::Rng(self.0);
        let v = r.next_u64();
        self.0 = r.0;
        v
    }
    pub fn next_u32(&mut self) -> u32 {
        (self.next_u64() >> 32) as u32
    }
    pub fn below(&mut self, n: u32) -> u32 {
        ((self.next_u32() as u64 * n as u64) >> 32) as u32
    }
}

/// A seed from `TGS_SEED` or the clock; printed so a failure can be re-run.
pub fn seed(test: &str) -> u64 {
    let s = std::env::var("TGS_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(1));
    eprintln!("{test}: seed {s} (re-run with TGS_SEED={s})");
    s
}

/// One context per test binary (device creation with validation is slow).
pub fn ctx_shared() -> &'static Arc<Context> {
    static CTX: std::sync::OnceLock<Arc<Context>> = std::sync::OnceLock::new();
    CTX.get_or_init(ctx)
}

/// The built-in `glass-tiny` scene in `dir`, written there unless a
/// previous call of this test binary already did; returns `dir`. Tests of
/// one binary run in parallel: one writes the scene while the others wait.
pub fn tiny_glass_scene(dir: &std::path::Path) -> std::path::PathBuf {
    static WRITING: std::sync::Mutex<()> = std::sync::Mutex::new(());
    let _one = WRITING.lock().unwrap_or_else(|e| e.into_inner());
    if !dir.join("transforms_train.json").is_file() {
        tgs::scene::make(&tgs::scene::spec("glass-tiny").unwrap(), dir, |_, _| {}).unwrap();
    }
    dir.to_path_buf()
}

/// Stage I alone on the `glass-tiny` scene ([`tiny_glass_scene`] in
/// `base/scene`), `iterations` long with the quick preset, into
/// `base/stage1` (no test renders, no checkpoints between): the start of
/// a test's `--from RUN --stages II` runs. Returns the run directory.
pub fn tiny_stage1(ctx: &Arc<Context>, base: &std::path::Path, iterations: u32) -> std::path::PathBuf {
    let out = base.join("stage1");
    let set = [format!("iterations={iterations}"), "stages=\"I\"".into(), "test_interval=0".into(), "checkpoint_interval=0".into()];
    let a = tgs::train::run::TrainArgs {
        dataset: Some(tiny_glass_scene(&base.join("scene"))),
        out: out.clone(),
        preset: Some("quick".into()),
        set: set.to_vec(),
        quiet: true,
        ..Default::default()
    };
    assert_eq!(tgs::train::run::train(ctx, &a).unwrap().iteration, iterations);
    out
}

/// A JSON file a run wrote (metrics.json, stages.json), parsed; a missing file panics naming it.
pub fn read_json(path: &std::path::Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))).unwrap()
}

/// Copy the directory tree `from` to `to` (made if missing).
pub fn copy_dir(from: &std::path::Path, to: &std::path::Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

/// A test's scratch directory, `<system temp>/tgs-<name>-<pid>`: emptied
/// when made, removed when dropped (also when the test fails, as
/// unwinding drops it), so test runs leave nothing behind.
pub struct TempDir(std::path::PathBuf);

impl TempDir {
    /// The path, with nothing there yet.
    pub fn new(name: &str) -> TempDir {
        let d = std::env::temp_dir().join(format!("tgs-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        let _ = std::fs::remove_file(&d);
        TempDir(d)
    }

    /// The path, created empty.
    pub fn created(name: &str) -> TempDir {
        let d = TempDir::new(name);
        std::fs::create_dir_all(&d.0).unwrap();
        d
    }

    pub fn path(&self) -> &std::path::Path {
        &self.0
    }
}

impl std::ops::Deref for TempDir {
    type Target = std::path::Path;
    fn deref(&self) -> &std::path::Path {
        &self.0
    }
}

impl AsRef<std::path::Path> for TempDir {
    fn as_ref(&self) -> &std::path::Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
        let _ = std::fs::remove_file(&self.0);
    }
}

/// The bytes of a version-2 checkpoint (`TGSCKPT2`) whose JSON header
/// `edit` changed, with its length and CRC-32 made right again (the arrays
/// after it unchanged): a checkpoint as another version of tgs, or another
/// run, would have written it.
pub fn edit_checkpoint_header(bytes: &[u8], edit: impl FnOnce(&mut serde_json::Value)) -> Vec<u8> {
    assert_eq!(&bytes[..8], b"TGSCKPT2");
    let hlen = u32::from_le_bytes(bytes[8..12].try_into().unwrap()) as usize;
    let mut header: serde_json::Value = serde_json::from_slice(&bytes[12..12 + hlen]).unwrap();
    edit(&mut header);
    let json = serde_json::to_vec(&header).unwrap();
    let mut out = bytes[..8].to_vec();
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(&json);
    out.extend(crc32fast::hash(&json).to_le_bytes());
    out.extend(&bytes[12 + hlen + 4..]);
    out
}
