//! Stage I: the scattering set (2DGS surfels) trained alone.
pub mod init;
pub mod knn;
pub mod model;
pub mod stage;

pub use crate::train::stages::rendered::Rendered;
pub use model::{ExternalStep, ScatteringModel, StepInput, StepOutput};
