//! Wall time of a run across `--resume`: metrics.json's `wall_s` of a stage,
//! `train_wall_s` and `total_wall_s` (and log.jsonl's `elapsed_s`) count the
//! time spent before an interruption too. Beside every checkpoint.bin the
//! driver writes checkpoint-time.json with the times at the checkpoint's
//! iteration; a resumed run starts its clocks from there (the work done
//! after that checkpoint is redone, so its time is not counted twice).

use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

pub const CLOCK_FILE: &str = "checkpoint-time.json";

/// Seconds spent before this process, at the checkpoint's iteration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Before {
    pub iteration: u32,
    /// In the stage that was running.
    pub stage_s: f64,
    /// In the training loop.
    pub train_s: f64,
    /// Since the run started.
    pub total_s: f64,
}

impl Before {
    /// The times saved with the checkpoint at `iteration`; zero when there
    /// are none or they belong to another checkpoint (a run killed between
    /// writing the two files, or one from before this file existed).
    pub fn read(out: &Path, iteration: u32) -> Before {
        std::fs::read(out.join(CLOCK_FILE))
            .ok()
            .and_then(|b| serde_json::from_slice::<Before>(&b).ok())
            .filter(|b| b.iteration == iteration && [b.stage_s, b.train_s, b.total_s].iter().all(|s| s.is_finite() && *s >= 0.0))
            .unwrap_or(Before { iteration, ..Before::default() })
    }
}

/// A run's three clocks: each an instant of this process plus the seconds
/// spent before it.
pub struct Clocks {
    total: (Instant, f64),
    train: (Instant, f64),
    stage: (Instant, f64),
}

impl Clocks {
    /// `total_start`: when this process began the run; `before`: what a
    /// resumed run had spent.
    pub fn new(total_start: Instant, before: Before) -> Clocks {
        let now = Instant::now();
        Clocks { total: (total_start, before.total_s), train: (now, before.train_s), stage: (now, before.stage_s) }
    }
    pub fn total_s(&self) -> f64 {
        self.total.1 + self.total.0.elapsed().as_secs_f64()
    }
    pub fn train_s(&self) -> f64 {
        self.train.1 + self.train.0.elapsed().as_secs_f64()
    }
    pub fn stage_s(&self) -> f64 {
        self.stage.1 + self.stage.0.elapsed().as_secs_f64()
    }
    /// A new stage begins now.
    pub fn next_stage(&mut self) {
        self.stage = (Instant::now(), 0.0);
    }
    /// Write checkpoint-time.json for the checkpoint just saved at `iteration`.
    pub fn save(&self, out: &Path, iteration: u32) -> Result<()> {
        let b = Before { iteration, stage_s: self.stage_s(), train_s: self.train_s(), total_s: self.total_s() };
        crate::export::atomic_write(&out.join(CLOCK_FILE), serde_json::to_string_pretty(&b)?.as_bytes())
    }
}
