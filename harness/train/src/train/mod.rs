//! Training: configuration, the stage-scheduled trainer, the stages (one
//! folder each under `stages/`), checkpoints, and the `tgs train` driver
//! (progress, logs, outputs).
pub mod args;
pub mod arrays;
pub mod checkpoint;
pub mod clock;
pub mod config;
pub mod divergence;
pub mod from;
pub mod live;
pub mod open;
pub mod piece_verdict;
pub mod records;
pub mod report;
pub mod run;
pub mod rundir;
pub mod schedule;
pub mod settings;
pub mod signals;
pub mod stage;
pub mod stages;
pub mod trainer;
pub mod validation;

pub use config::TrainConfig;
pub use schedule::{Schedule, Stage};
pub use trainer::{StepReport, Trainer};

/// A learning rate log-linear from `a` (t = 0) to `b` (t = 1), t clamped.
pub(crate) fn log_lerp(a: f32, b: f32, t: f64) -> f64 {
    let t = t.clamp(0.0, 1.0);
    let (a, b) = (a.max(1e-30) as f64, b.max(1e-30) as f64);
    (a.ln() * (1.0 - t) + b.ln() * t).exp()
}

/// The mean of `v` in f64, summed in order (0 when empty).
pub(crate) fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len().max(1) as f64
}

/// The inverse of the sigmoid: the raw value whose activation is `p`.
pub(crate) fn logit(p: f32) -> f32 {
    (p / (1.0 - p)).ln()
}
