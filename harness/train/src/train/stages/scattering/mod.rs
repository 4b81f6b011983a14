//! Stage I: the scattering set (2DGS surfels) trained alone.
pub mod init;
pub mod knn;
pub mod model;
mod stage;

pub use model::{Rendered, ScatteringModel, StepInput, StepOutput};
