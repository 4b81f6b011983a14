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
//! (`kind.rs`), listed in run order by [`later`]: a new stage is a folder
//! and an entry in [`BUILT_IN`] (its settings section a field of
//! `TrainConfig`, presets and validation in its `config.rs`), or a kind
//! given to [`register`] by a program that embeds tgs (its section then
//! kept as TOML in `TrainConfig::sections`). `composite.rs` is the deferred composite's step they share (each stage's
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

use crate::train::stage::Stage;
use anyhow::{bail, Result};
use std::sync::RwLock;

/// The stages after Stage I that ship with tgs, in run order.
pub static BUILT_IN: [&dyn LaterKind; 2] = [&reflection::stage::Kind, &light_field::stage::Kind];

/// Stages added by [`register`], run after the built-in ones in the order added.
static REGISTERED: RwLock<Vec<&'static dyn LaterKind>> = RwLock::new(Vec::new());

/// Every stage after Stage I, in run order: [`BUILT_IN`], then the registered.
pub fn later() -> Vec<&'static dyn LaterKind> {
    let extra = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
    BUILT_IN.iter().copied().chain(extra.iter().copied()).collect()
}

/// Add `kind` as the last stage (for the whole process): the schedule,
/// the `stages` setting, settings files and `--set` (its
/// [`LaterKind::settings`]), checkpoints, `--from`, `--resume` and the
/// renderers see it. Its name and settings key must be new.
pub fn register(kind: &'static dyn LaterKind) -> Result<()> {
    let settings = toml::Table::try_from(crate::train::TrainConfig::default()).map_err(anyhow::Error::from)?;
    let mut extra = REGISTERED.write().unwrap_or_else(|e| e.into_inner());
    let key_taken = BUILT_IN.iter().chain(extra.iter()).any(|k| k.key() == kind.key()) || settings.contains_key(kind.key());
    if Stage::all().contains(&kind.stage()) || key_taken {
        bail!("stage {} ({}): its name or settings key is taken", kind.stage().name(), kind.key());
    }
    if let Some(s) = kind.settings().filter(|s| s.key != kind.key()) {
        bail!("stage {}: its settings section is named '{}', not its key '{}'", kind.stage().name(), s.key, kind.key());
    }
    crate::train::stage::add(kind.stage(), kind.settings());
    extra.push(kind);
    Ok(())
}
