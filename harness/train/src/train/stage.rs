//! A training stage's identity: its name, the order of all stages, and
//! the settings sections of stages added at run time (`stages::register`).
//! A leaf (it depends on no module of the crate), so that settings, the
//! schedule and every stage can name stages without depending on one another.

use std::sync::RwLock;

/// A training stage (paper §3–4), by the name logs, metrics and
/// `--stages` give it: Stage I ([`Stage::SCATTERING`]) and the later
/// stages, each of which also names itself in its kind (its folder's
/// `stage.rs`; `stages::later()` lists the kinds in the same order, a
/// test holds the built-in lists together).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stage(pub &'static str);

impl Default for Stage {
    fn default() -> Stage {
        Stage::SCATTERING
    }
}

impl Stage {
    /// Stage I: the scattering set alone (2DGS).
    pub const SCATTERING: Stage = Stage("I");

    /// The stages that ship with tgs, in run order.
    pub const BUILT_IN: [Stage; 3] = [Stage::SCATTERING, Stage("II"), Stage("III")];

    /// Every stage in run order: [`Stage::BUILT_IN`], then those added.
    pub fn all() -> Vec<Stage> {
        let added = ADDED.read().unwrap_or_else(|e| e.into_inner());
        Stage::BUILT_IN.into_iter().chain(added.iter().map(|a| a.0)).collect()
    }

    pub fn name(self) -> &'static str {
        self.0
    }

    /// The stage of [`Stage::all`] named `name` ("II", ...).
    pub fn named(name: &str) -> Option<Stage> {
        Stage::all().into_iter().find(|s| s.name() == name)
    }

    /// 1 for Stage I, 2 for the first later stage, ...: the number in
    /// the run directory's `checkpoint-stageN.bin` and `renders/stageN`
    /// (0 for a stage not in [`Stage::all`]).
    pub fn number(self) -> usize {
        Stage::all().iter().position(|&s| s == self).map(|i| i + 1).unwrap_or(0)
    }
}

/// The settings section of a stage added by `stages::register` (the
/// built-in stages' sections are fields of `TrainConfig`): `[key]` in
/// TOML, `--set key.NAME=V`, kept as TOML in `TrainConfig::sections`.
#[derive(Clone, Copy)]
pub struct StageSettings {
    pub key: &'static str,
    /// The section under a preset ("paper" or "quick").
    pub defaults: fn(&str) -> toml::Table,
    /// Check a section's values (an error names the setting).
    pub check: fn(&toml::Table) -> anyhow::Result<()>,
}

/// The stages added, in order, with their settings sections.
static ADDED: RwLock<Vec<(Stage, Option<StageSettings>)>> = RwLock::new(Vec::new());

/// Append an added stage to [`Stage::all`] (`stages::register` checks it first).
pub(crate) fn add(stage: Stage, settings: Option<StageSettings>) {
    ADDED.write().unwrap_or_else(|e| e.into_inner()).push((stage, settings));
}

/// The settings sections of the stages added, in order.
pub fn added_settings() -> Vec<StageSettings> {
    ADDED.read().unwrap_or_else(|e| e.into_inner()).iter().filter_map(|a| a.1).collect()
}
