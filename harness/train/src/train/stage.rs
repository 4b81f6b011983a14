//! A training stage's identity: its name, and the order of all stages.
//! A leaf (it depends on nothing), so that settings, the schedule and
//! every stage can name stages without depending on one another.

/// A training stage (paper §3–4), by the name logs, metrics and
/// `--stages` give it: Stage I ([`Stage::SCATTERING`]) and the later
/// stages, each of which also names itself in its folder's `stage.rs`
/// (`stages::LATER` lists their kinds in the order of [`Stage::ALL`]; a
/// test holds the two lists together).
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

    /// Every stage in run order.
    pub const ALL: [Stage; 3] = [Stage::SCATTERING, Stage("II"), Stage("III")];

    pub fn name(self) -> &'static str {
        self.0
    }

    /// The stage of [`Stage::ALL`] named `name` ("II", ...).
    pub fn named(name: &str) -> Option<Stage> {
        Stage::ALL.into_iter().find(|s| s.name() == name)
    }

    /// 1 for Stage I, 2 for the first later stage, ...: the number in
    /// the run directory's `checkpoint-stageN.bin` and `renders/stageN`
    /// (0 for a stage not in [`Stage::ALL`]).
    pub fn number(self) -> usize {
        Stage::ALL.iter().position(|&s| s == self).map(|i| i + 1).unwrap_or(0)
    }
}
