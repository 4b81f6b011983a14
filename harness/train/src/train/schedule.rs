//! The stages (paper §3–4) and the schedule that runs them in order: each
//! entry a stage and its iteration count, a stage maybe run twice
//! (`reflection.reseed`).

use super::config::TrainConfig;
pub use super::stage::Stage;
use super::stages::later;

/// The stage schedule: each stage with its iteration count, run in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Schedule {
    pub stages: Vec<(Stage, u32)>,
}

impl Schedule {
    /// Stage I, then each later stage the settings name (`stages`), in
    /// order; with `reflection.reseed` and more than one later stage named,
    /// those run once more (Stage II seeded again after Stage III).
    pub fn from_config(cfg: &TrainConfig) -> Schedule {
        let mut stages = vec![(Stage::SCATTERING, cfg.iterations)];
        let named = cfg.stage_list().unwrap_or_default();
        let later: Vec<(Stage, u32)> = later().into_iter().filter(|k| named.contains(&k.stage().name())).map(|k| (k.stage(), k.iterations(cfg))).collect();
        stages.extend(&later);
        if cfg.reflection.reseed && later.len() > 1 {
            stages.extend(&later);
        }
        Schedule { stages }
    }
    /// The index in `stages` of global iteration `it` (1-based).
    pub fn entry_at(&self, it: u32) -> Option<usize> {
        let mut start = 0;
        for (i, &(_, n)) in self.stages.iter().enumerate() {
            if it > start && it <= start + n {
                return Some(i);
            }
            start += n;
        }
        None
    }
    /// Entry `i`'s round: 1, or 2 for a stage run again (reflection.reseed).
    pub fn round(&self, i: usize) -> u32 {
        let s = self.stages.get(i).map(|e| e.0);
        1 + self.stages[..i.min(self.stages.len())].iter().filter(|e| Some(e.0) == s).count() as u32
    }
    /// Entry `i`'s name in logs and metrics: "II", or "II.2" in round 2.
    pub fn label(&self, i: usize) -> String {
        let name = self.stages.get(i).map(|e| e.0.name()).unwrap_or("?");
        match self.round(i) {
            1 => name.to_string(),
            r => format!("{name}.{r}"),
        }
    }
    /// The iterations of the entry named `label`.
    pub fn iterations_of(&self, label: &str) -> u32 {
        (0..self.stages.len()).find(|&i| self.label(i) == label).map(|i| self.stages[i].1).unwrap_or(0)
    }
    /// First global iteration of `stage` minus one (its iterations are start+1..).
    pub fn start_of(&self, stage: Stage) -> u32 {
        self.stages.iter().take_while(|s| s.0 != stage).map(|s| s.1).sum()
    }
    /// Drop entry `i` and those after it (a stage that decided not to run).
    pub fn end_before(&mut self, i: usize) {
        self.stages.truncate(i);
    }
    pub fn total(&self) -> u32 {
        self.stages.iter().map(|s| s.1).sum()
    }
    /// The stage of global iteration `it` (1-based) and the iteration within it.
    pub fn at(&self, it: u32) -> Option<(Stage, u32)> {
        let i = self.entry_at(it)?;
        let start: u32 = self.stages[..i].iter().map(|e| e.1).sum();
        Some((self.stages[i].0, it - start))
    }
}
