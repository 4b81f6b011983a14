//! A stage after Stage I as the run knows it before the stage exists: its
//! place in the schedule, its transition from the stage before it, and its
//! part of a checkpoint, the settings `--resume`, `--from` and `tgs eval`
//! may change. Each later stage has one [`LaterKind`] (a unit struct in
//! its `stage.rs`), listed in run order by [`super::later`]; the schedule,
//! the trainer, the checkpoint, the settings checks and the `tgs train`
//! driver go through that list, so a new stage is its folder, its kind
//! there and its settings section.

use super::layer::RenderLayer;
use super::shared::{LaterStage, Shared};
use crate::train::config::TrainConfig;
use crate::train::stage::{Stage, StageSettings};
use crate::train::stages::reflection::decision::ReflDecision;
use anyhow::{Context as _, Result};
use std::path::Path;
use std::sync::Arc;
use tgs_engine::Context;

/// Where a transition may write what it measured (the run directory); none
/// in benchmarks and tests that only train.
pub struct RunPaths<'a> {
    pub dir: &'a Path,
    /// The dataset's directory, which nothing is written into.
    pub dataset: &'a Path,
    /// The training views' names, in the trainer's order.
    pub view_names: &'a [String],
}

/// What a stage's transition is given.
pub struct Transition<'a> {
    pub shared: Shared<'a>,
    /// The later stage that ran until now (None after Stage I), handed
    /// over: the new stage takes what it needs from it.
    pub previous: Option<Box<dyn LaterStage>>,
    /// The Stage I residual's decision so far (kept across a resume and
    /// into the later stages' checkpoints); the stage that makes one
    /// replaces it.
    pub decision: &'a mut Option<ReflDecision>,
    /// 1, or 2 for a stage run again (`reflection.reseed`).
    pub round: u32,
    /// The schedule's name of the starting entry ("II", "III.2", ...).
    pub label: String,
    pub files: Option<RunPaths<'a>>,
    /// Progress lines go to stderr unless quiet.
    pub quiet: bool,
}

/// What a transition did.
pub struct Begun {
    /// The stage's model (or the previous one, kept on a resume inside
    /// the stage); None when it does not run.
    pub model: Option<Box<dyn LaterStage>>,
    /// Whether the stage runs: when not, the schedule ends before it.
    pub runs: bool,
    /// The line the driver prints.
    pub message: String,
    /// Fields the driver adds to the stage's `begin` event in log.jsonl.
    pub event: serde_json::Map<String, serde_json::Value>,
}

/// A stage after Stage I, before and between its runs.
pub trait LaterKind: Sync {
    fn stage(&self) -> Stage;
    /// Its key in a checkpoint's header (the JSON object holding its state).
    fn key(&self) -> &'static str;
    /// Its iteration count when the settings run it.
    fn iterations(&self, cfg: &TrainConfig) -> u32;
    /// Its settings section when `TrainConfig` has no field for it (a
    /// stage added by [`super::register`]); None for the built-in stages.
    fn settings(&self) -> Option<StageSettings> {
        None
    }
    /// The settings of its section (`[key]` in TOML, `--set key.NAME=V`;
    /// the section is named by [`LaterKind::key`]) that `--resume` may
    /// change, as dotted keys.
    fn resumable(&self) -> &'static [&'static str];
    /// The settings of its section that change only what a trained model
    /// outputs, not what it learns (`tgs eval --set` may change them).
    fn output_settings(&self) -> &'static [&'static str] {
        &[]
    }
    /// Settings of the stages before it that a `--from RUN` starting at
    /// this stage (RUN's earlier stages kept) may still change.
    fn frees_earlier_settings(&self) -> &'static [&'static str] {
        &[]
    }
    /// Whether it trains the scattering set under `cfg` (then a run that
    /// went through it no longer holds Stage I's scattering set).
    fn trains_scattering(&self, cfg: &TrainConfig) -> bool;
    /// Check, before Stage I trains, the inputs it will read (files its
    /// settings name), for the training views `view_names` seen by
    /// `cameras`: a bad one fails now rather than after Stage I.
    fn preflight(&self, cfg: &TrainConfig, view_names: &[String], cameras: &[tgs_pipelines::Camera]) -> Result<()> {
        let _ = (cfg, view_names, cameras);
        Ok(())
    }
    /// Whether the next iteration, which belongs to this stage, needs
    /// [`LaterKind::begin`] first, given the later stage that is running
    /// and whether the frozen scattering colours are cached.
    fn needs_begin(&self, running: Option<&dyn LaterStage>, cache_empty: bool) -> bool {
        let _ = cache_empty;
        running.map(|m| m.stage()) != Some(self.stage())
    }
    /// The transition into the stage.
    fn begin(&self, t: Transition<'_>) -> Result<Begun>;
    /// The model from its checkpoint part: `header` (this stage's JSON
    /// object) and the arrays after the scattering set's; also the
    /// decision the header kept.
    fn restore(&self, header: &serde_json::Value, ctx: &Arc<Context>, cfg: &TrainConfig, arrays: Vec<Vec<f32>>) -> Result<(Box<dyn LaterStage>, ReflDecision)>;
    /// Its reflection layer for a renderer, from the same part (the
    /// parameters only) onto `ctx`.
    fn render_layer(&self, header: &serde_json::Value, cfg: &TrainConfig, arrays: Vec<Vec<f32>>, ctx: &Arc<Context>) -> Result<Box<dyn RenderLayer>>;
    /// The names and lengths of the arrays its checkpoint part holds, in
    /// file order (every later stage's header keeps them as `arrays`).
    fn arrays(&self, header: &serde_json::Value) -> Result<Vec<(String, usize)>> {
        serde_json::from_value(header.get("arrays").cloned().unwrap_or_default()).with_context(|| format!("the {} state's array list", self.key()))
    }
    /// What it adds, named for the log ("reflection set"), when a
    /// validation slice it does not raise sends the run back to the stage
    /// before (whose model is then the result); None: its verdict is only
    /// reported.
    fn dropped_unless_kept(&self) -> Option<&'static str> {
        None
    }
    /// The files it writes directly into the run directory.
    fn files(&self) -> &'static [&'static str] {
        &[]
    }
    /// The SH degree the frozen scattering layer is rendered at under this
    /// stage, for a Stage I trained up to `stage1` (Stage I's own by default).
    fn scattering_sh(&self, cfg: &TrainConfig, stage1: u32) -> u32 {
        let _ = cfg;
        stage1
    }
}

/// The later stage whose checkpoint key is `key`.
pub fn by_key(key: &str) -> Option<&'static dyn LaterKind> {
    super::later().into_iter().find(|k| k.key() == key)
}

/// Whether the dotted setting `k` lies in `kind`'s settings section.
pub fn in_section(kind: &dyn LaterKind, k: &str) -> bool {
    k.strip_prefix(kind.key()).is_some_and(|rest| rest.starts_with('.'))
}

/// The later stage named `stage`.
pub fn by_stage(stage: Stage) -> Option<&'static dyn LaterKind> {
    super::later().into_iter().find(|k| k.stage() == stage)
}

/// A header's JSON part as `T`, the error naming the stage.
pub(crate) fn parse<T: serde::de::DeserializeOwned>(k: &dyn LaterKind, header: &serde_json::Value) -> Result<T> {
    T::deserialize(header).with_context(|| format!("the checkpoint's {} header", k.key()))
}
