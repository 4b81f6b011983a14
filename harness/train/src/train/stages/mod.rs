//! The three stages, one folder each: `scattering` (Stage I, the 2DGS
//! scattering set), `reflection` (Stage II, the reflection set lit by a
//! cube map) and `light_field` (Stage III, the reflection light-field MLP).
//! Each folder holds the stage's model (`model.rs`), its settings
//! (`config.rs`, Stages II and III; Stage I's are the top-level ones), its
//! part of the checkpoint (`checkpoint.rs`), what it writes
//! (`outputs.rs`), its reflection layer as a renderer draws it
//! (`render.rs`, behind `layer.rs`'s trait) and `stage.rs`: the transition from the previous stage
//! and one iteration as the trainer calls it. The later stages implement
//! [`LaterStage`] (`shared.rs`), which the trainer drives them through,
//! and are begun, scheduled and checkpointed through their [`LaterKind`]
//! (`kind.rs`), listed in run order in [`LATER`]: a new stage is a folder,
//! an entry in that list, its name in `Stage::ALL` and its settings
//! section (a field of `TrainConfig`; presets and validation in its
//! `config.rs`). `composite.rs` is the deferred composite's step they share (each stage's
//! `light.rs` holds what differs: a cube map or the light-field network); `views.rs`
//! and `rendered.rs` what every stage reads and returns; `kept_views.rs`
//! the training views' binnings kept for a set whose geometry is frozen.
pub mod composite;
pub mod kept_views;
pub mod kind;
pub mod layer;
pub mod light_field;
pub mod reflection;
pub mod rendered;
pub mod scattering;
pub mod shared;
pub mod views;

pub use kind::{Begun, LaterKind, RunPaths, Transition};
pub use shared::{Iteration, LaterStage, ScatCache, Shared};
pub use views::Views;

/// The stages after Stage I, in run order.
pub static LATER: [&dyn LaterKind; 2] = [&reflection::stage::Kind, &light_field::stage::Kind];
