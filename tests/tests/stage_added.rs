//! A stage added from outside tgs (`stages::register`): a fourth stage,
//! "IV" with the settings section `[polish]`, that trains Stage III's
//! light field for `polish.iterations` more iterations and writes
//! `polish.json`. Everything a stage plugs into sees it without naming it:
//! the `stages` setting and `--set`, its presets and validation, the
//! schedule, the run directory's files, the checkpoint (a run stopped in
//! it resumes), `--from RUN --stages IV`, and the renderers (`tgs render`'s
//! and the embedding one). Its own test binary: the list is the process's.

use serde::{Deserialize, Serialize};
use std::any::Any;
use std::path::Path;
use std::sync::Arc;
use tgs::embed::SceneRenderer;
use tgs::train::checkpoint;
use tgs::train::run::{train, TrainArgs};
use tgs::train::rundir::run_files;
use tgs::train::stage::StageSettings;
use tgs::train::stages::kind::by_key;
use tgs::train::stages::layer::RenderLayer;
use tgs::train::stages::reflection::decision::ReflDecision;
use tgs::train::stages::rendered::ReflRendered;
use tgs::train::stages::scattering::StepOutput;
use tgs::train::stages::{register, Begun, Iteration, LaterKind, LaterStage, Shared, Transition};
use tgs::train::{Stage, TrainConfig};
use tgs_engine::{Buffer, Context};
use tgs_pipelines::{Camera, TrainableSet};
use tgs_tests::ctx_shared;
use tgs_tests::raster_util::bits;

const IV: Stage = Stage("IV");

/// `[polish]`: the stage's settings.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
struct PolishConfig {
    iterations: u32,
}

impl Default for PolishConfig {
    fn default() -> Self {
        PolishConfig { iterations: 30 }
    }
}

fn settings(cfg: &TrainConfig) -> PolishConfig {
    cfg.section("polish").expect("validated")
}

fn polish_defaults(preset: &str) -> toml::Table {
    let iterations = if preset == "quick" { 30 } else { 300 };
    toml::Table::try_from(PolishConfig { iterations }).expect("a table")
}

fn polish_check(t: &toml::Table) -> anyhow::Result<()> {
    let c: PolishConfig = t.clone().try_into()?;
    anyhow::ensure!(c.iterations > 0, "polish.iterations must be at least 1");
    Ok(())
}

/// Stage IV as the schedule and the checkpoint know it.
struct Kind;

/// Stage III's model, trained on under another name.
struct Polish {
    inner: Box<dyn LaterStage>,
}

fn light_field() -> &'static dyn LaterKind {
    by_key("light_field").unwrap()
}

impl LaterKind for Kind {
    fn stage(&self) -> Stage {
        IV
    }
    fn key(&self) -> &'static str {
        "polish"
    }
    fn settings(&self) -> Option<StageSettings> {
        Some(StageSettings { key: "polish", defaults: polish_defaults, check: polish_check })
    }
    fn iterations(&self, cfg: &TrainConfig) -> u32 {
        settings(cfg).iterations
    }
    fn resumable(&self) -> &'static [&'static str] {
        &["polish.iterations"]
    }
    fn trains_scattering(&self, cfg: &TrainConfig) -> bool {
        light_field().trains_scattering(cfg)
    }
    fn begin(&self, t: Transition<'_>) -> anyhow::Result<Begun> {
        let inner = t.previous.filter(|m| m.stage() == Stage("III")).ok_or_else(|| anyhow::anyhow!("Stage IV starts from Stage III's model"))?;
        let message = format!("Stage {}: polishing Stage III's light field", t.label);
        Ok(Begun { model: Some(Box::new(Polish { inner })), runs: true, message, event: serde_json::Map::new() })
    }
    fn restore(&self, header: &serde_json::Value, ctx: &Arc<Context>, cfg: &TrainConfig, arrays: Vec<Vec<f32>>) -> anyhow::Result<(Box<dyn LaterStage>, ReflDecision)> {
        let (inner, d) = light_field().restore(&header["inner"], ctx, cfg, arrays)?;
        Ok((Box::new(Polish { inner }), d))
    }
    fn render_layer(&self, header: &serde_json::Value, cfg: &TrainConfig, arrays: Vec<Vec<f32>>, ctx: &Arc<Context>) -> anyhow::Result<Box<dyn RenderLayer>> {
        light_field().render_layer(&header["inner"], cfg, arrays, ctx)
    }
    fn files(&self) -> &'static [&'static str] {
        &["polish.json", "light_field.safetensors"]
    }
    fn scattering_sh(&self, cfg: &TrainConfig, stage1: u32) -> u32 {
        light_field().scattering_sh(cfg, stage1)
    }
}

impl LaterStage for Polish {
    fn stage(&self) -> Stage {
        IV
    }
    fn iterate(&mut self, s: Shared<'_>, x: &Iteration) -> anyhow::Result<StepOutput> {
        self.inner.iterate(s, x)
    }
    fn render(&mut self, cam: &Camera, scat: &Buffer<f32>) -> anyhow::Result<ReflRendered> {
        self.inner.render(cam, scat)
    }
    fn set(&self) -> &TrainableSet {
        self.inner.set()
    }
    fn write_outputs(&self, out: &Path) -> anyhow::Result<()> {
        self.inner.write_outputs(out)?;
        Ok(std::fs::write(out.join("polish.json"), format!("{{\"gaussians\": {}}}\n", self.set().params.n))?)
    }
    fn into_set(self: Box<Self>) -> TrainableSet {
        self.inner.into_set()
    }
    fn save_state<'a>(&'a self, d: &ReflDecision, bufs: &mut Vec<(&'a Buffer<f32>, usize)>) -> anyhow::Result<serde_json::Value> {
        let inner = self.inner.save_state(d, bufs)?;
        Ok(serde_json::json!({ "arrays": inner["arrays"].clone(), "inner": inner }))
    }
    fn take_coverage(&mut self) -> Option<f64> {
        self.inner.take_coverage()
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

fn args(out: &Path, set: &[&str]) -> TrainArgs {
    let _ = std::fs::remove_dir_all(out);
    let scene = tgs_tests::tiny_glass_scene(&Path::new(env!("CARGO_TARGET_TMPDIR")).join("stage-added-scene"));
    let base = ["iterations=200", "reflection.iterations=40", "light_field.iterations=40", "polish.iterations=20", "test_interval=0", "checkpoint_interval=0"];
    let set = base.iter().chain(set).map(|s| s.to_string()).collect();
    TrainArgs { dataset: Some(scene), out: out.to_path_buf(), preset: Some("quick".into()), set, stages: Some("I,II,III,IV".into()), quiet: true, ..Default::default() }
}

fn arrays(run: &Path) -> (checkpoint::Header, Vec<Vec<f32>>) {
    checkpoint::read(&run.join("checkpoint.bin")).unwrap()
}

fn same(a: &[Vec<f32>], b: &[Vec<f32>], what: &str) {
    assert_eq!(a.len(), b.len(), "{what}: array count");
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        assert!(bits(x) == bits(y), "{what}: array {i} differs");
    }
}

#[test]
fn a_stage_added_at_run_time_is_seen_by_settings_checkpoints_from_and_renderers() {
    register(&Kind).unwrap();
    let e = format!("{:#}", register(&Kind).unwrap_err());
    assert!(e.contains("taken"), "{e}");

    // Settings: its section in both presets, `--set`, its validation, the `stages` list.
    assert_eq!(Stage::all(), [Stage("I"), Stage("II"), Stage("III"), IV]);
    assert_eq!(Stage::named("IV").map(Stage::number), Some(4));
    assert_eq!((settings(&TrainConfig::quick()).iterations, settings(&TrainConfig::paper()).iterations), (30, 300));
    let mut cfg = TrainConfig::quick();
    cfg.set("polish.iterations=7").unwrap();
    assert_eq!(settings(&cfg).iterations, 7);
    for (bad, says) in
        [("polish.iterations=0", "polish.iterations must be at least 1"), ("polish.colour=1", "unknown setting 'polish.colour'"), ("stages=I,II,IV", "\"I,II,III,IV\"")]
    {
        let e = format!("{:#}", TrainConfig::quick().set(bad).unwrap_err());
        assert!(e.contains(says), "{bad}: {e}");
    }
    cfg.set("stages=\"I,II,III,IV\"").unwrap();
    assert!(tgs::train::args::resumable_settings().contains(&"polish.iterations"));
    let files = run_files();
    assert!(["checkpoint-stage3.bin", "polish.json"].iter().all(|f| files.iter().any(|g| g == f)), "{files:?}");
    // A settings file names the section too, and a checkpoint's settings keep it.
    let text = toml::to_string(&cfg).unwrap();
    assert!(text.contains("[polish]\niterations = 7"), "{text}");

    // Training through it: the schedule, its outputs, the stage-end checkpoints.
    let ctx = ctx_shared();
    let base = tgs_tests::TempDir::new("stage-added");
    let full = base.join("full");
    assert_eq!(train(ctx, &args(&full, &[])).unwrap().iteration, 300);
    let m: serde_json::Value = serde_json::from_slice(&std::fs::read(full.join("metrics.json")).unwrap()).unwrap();
    let names: Vec<&str> = m["stages"].as_array().unwrap().iter().map(|s| s["stage"].as_str().unwrap()).collect();
    assert_eq!(names, ["I", "II", "III", "IV"]);
    for f in ["polish.json", "light_field.safetensors", "checkpoint-stage3.bin", "config.toml"] {
        assert!(full.join(f).is_file(), "missing {f}");
    }
    assert!(std::fs::read_to_string(full.join("config.toml")).unwrap().contains("[polish]\niterations = 20"));
    let (h, want) = arrays(&full);
    assert_eq!(h.later_state().unwrap().map(|(k, _)| k.key()), Some("polish"));
    assert!(h.holds(IV) && want.iter().all(|a| a.iter().all(|v| v.is_finite())));

    // Ended inside Stage IV (its checkpoint part), then resumed with
    // Stage IV longer (a setting its kind lets `--resume` change): bit-identical.
    let part = base.join("part");
    assert_eq!(train(ctx, &args(&part, &["polish.iterations=10"])).unwrap().iteration, 290);
    let resume = TrainArgs { out: part.clone(), resume: true, set: vec!["polish.iterations=20".into()], quiet: true, ..Default::default() };
    assert_eq!(train(ctx, &resume).unwrap().iteration, 300);
    same(&arrays(&part).1, &want, "resumed inside Stage IV");

    // `--from RUN --stages IV` starts from RUN's end of Stage III: bit-identical again.
    let from = base.join("from");
    let _ = std::fs::remove_dir_all(&from);
    let a = TrainArgs { out: from.clone(), from: Some(full.clone()), dataset: None, preset: None, stages: Some("IV".into()), set: vec![], quiet: true, ..Default::default() };
    assert_eq!(train(ctx, &a).unwrap().iteration, 300);
    same(&arrays(&from).1, &want, "--from RUN --stages IV");

    // The renderers: `tgs render`'s (the trainer restored) and the embedding one, bit for bit.
    let (mut tr, _) = tgs::train::run::open_run(ctx, &full).unwrap();
    let mut scene = SceneRenderer::load(ctx, &full).unwrap();
    assert_eq!(scene.stage, "IV");
    assert!(scene.counts().1 > 0);
    for (name, cam) in tgs::embed::run_cameras(&full).unwrap() {
        let n = SceneRenderer::output_len(cam.width, cam.height);
        let got = scene.render(&cam).unwrap();
        let want = tr.render(&cam).unwrap().planes[..n].to_vec();
        assert!(got.iter().all(|v| v.is_finite()) && bits(&got) == bits(&want), "{name}: the embedding render differs from tgs render's");
    }
}
