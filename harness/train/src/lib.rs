//! tgs training: the three stages (`train::stages`), the trainer that
//! drives them on a schedule, settings, checkpoints, the `tgs train`
//! driver (`train::run`), and the test-view evaluation it reports
//! (`eval`, with `lpips`).

pub mod eval;
pub mod lpips;
pub mod train;

pub use tgs_dataset::{data, export, lock, outdir, scene};
