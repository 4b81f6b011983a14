//! Stage III: the reflection light field Phi(x, w), an MLP replacing Stage
//! II's cube map, over the reflection set with its geometry frozen.
pub mod checkpoint;
pub mod config;
mod light;
pub mod model;
pub mod outputs;
pub mod render;
pub mod settings;
pub mod stage;

pub use crate::train::stages::kept_views::KeepAs;
pub use crate::train::stages::reflection::bounds::normalization_box;
pub use model::{LightFieldModel, LightFieldStepInput, MlpParams};
