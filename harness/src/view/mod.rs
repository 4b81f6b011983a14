//! `tgs view RUN`: a window on a trained run. It renders the deferred
//! composite through [`crate::embed::SceneRenderer`] into the frame's
//! command buffer on the window's own device and queue, with orbit, pan,
//! zoom and fly controls, the dataset's cameras, the layers `tgs render`
//! writes, the run's Stage I/II/III checkpoints and screenshots.

mod app;
pub mod controls;
mod gpu;
pub mod input;
pub mod scene;
mod shot;

use anyhow::{bail, Result};
use std::path::PathBuf;
use tgs_engine::DeviceSelector;

/// What `tgs view` was asked for.
pub struct ViewArgs {
    pub run: PathBuf,
    /// Window size; default the first camera's size (scaled up to at least 400 wide).
    pub size: Option<(u32, u32)>,
    /// Start at this dataset camera (of the test cameras, or the training ones with `train`).
    pub camera: usize,
    pub train: bool,
    /// Replay these actions, then quit.
    pub script: Option<PathBuf>,
    /// Where screenshots go (default RUN/screenshots).
    pub shots: Option<PathBuf>,
    pub device: DeviceSelector,
}

/// Open the window and run until it closes. Without a display this says
/// so and names `tgs render`, the headless way to the same images.
pub fn view(a: &ViewArgs) -> Result<()> {
    // The run first: a missing or corrupt one gets the other commands' errors, display or not.
    if !a.run.is_dir() {
        bail!("{}: no such run directory", a.run.display());
    }
    crate::train::checkpoint::read(&a.run.join(crate::train::rundir::CHECKPOINT))?;
    let display = ["DISPLAY", "WAYLAND_DISPLAY"].iter().any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()));
    if !display {
        bail!(
            "no display to open a window on (neither DISPLAY nor WAYLAND_DISPLAY is set); `tgs render {}` writes the same images headless (or run under xvfb-run)",
            a.run.display()
        );
    }
    if let Some(s) = &a.script {
        // Read before the window opens, so a bad script fails at once.
        input::read_script(s)?;
    }
    app::run(a)
}
