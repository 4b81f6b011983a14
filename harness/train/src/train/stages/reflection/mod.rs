//! Stage II: the reflection set, seeded where the Stage I residual calls
//! for it and lit by a cube map, composited over the frozen Stage I render.
pub mod checkpoint;
pub mod config;
pub mod env_init;
pub mod model;
pub mod seed;
pub mod outputs;
mod stage;
pub mod view_dependence;

pub use model::{residual, PhiLayers, ReflRendered, ReflStepInput, ReflectionModel, ScatTrain};
pub(crate) use model::R_PLANE;
pub use stage::{env_proxy, reflection_decides, EnvInit, ReflDecision};
