//! Stage II: the reflection set, seeded where the Stage I residual calls
//! for it and lit by a cube map, composited over the frozen Stage I render.
pub mod bounds;
pub mod checkpoint;
pub mod config;
pub mod decision;
pub mod env_init;
mod light;
pub mod masks;
pub mod model;
pub mod normal_gate;
pub mod outputs;
pub mod pieces;
pub mod render;
pub mod seed;
pub mod settings;
pub mod stage;
pub mod view_dependence;

pub use crate::train::stages::rendered::{PhiLayers, ReflRendered};
pub use model::{residual, ReflStepInput, ReflectionModel, ScatTrain};
pub use normal_gate::{reflection_decides, NormalGate};
pub use stage::{env_proxy, EnvInit, ReflDecision};
