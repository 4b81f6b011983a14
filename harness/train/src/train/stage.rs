//! A training stage's identity: its name, and the order of all stages
//! (Stage I, then the later stages' list, `stages::LATER`, where each
//! later stage names itself).

/// A training stage (paper §3–4), by the name logs, metrics and
/// `--stages` give it: Stage I ([`Stage::SCATTERING`]) and the later
/// stages, each of which names itself in its folder's `stage.rs`.
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

    /// Every stage in run order: Stage I, then `stages::LATER`'s.
    pub fn all() -> impl Iterator<Item = Stage> {
        std::iter::once(Stage::SCATTERING).chain(super::stages::LATER.iter().map(|k| k.stage()))
    }

    pub fn name(self) -> &'static str {
        self.0
    }

    /// The stage of [`Stage::all`] named `name` ("II", ...).
    pub fn named(name: &str) -> Option<Stage> {
        Stage::all().find(|s| s.name() == name)
    }

    /// 1 for Stage I, 2 for the first later stage, ...: the number in
    /// the run directory's `checkpoint-stageN.bin` and `renders/stageN`
    /// (0 for a stage not in [`Stage::all`]).
    pub fn number(self) -> usize {
        Stage::all().position(|s| s == self).map(|i| i + 1).unwrap_or(0)
    }
}
