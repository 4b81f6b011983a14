//! Training: configuration, initialisation, the stage-scheduled trainer,
//! checkpoints, and the `tgs train` driver (progress, logs, outputs).
pub mod checkpoint;
pub mod config;
pub mod init;
pub mod lightfield;
pub mod rng;
pub mod run;
pub mod reflection;
pub mod scattering;
pub mod seed;
pub mod trainer;

pub use config::TrainConfig;
pub use trainer::{Schedule, Stage, StepReport, Trainer};
