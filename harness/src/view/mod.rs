//! `tgs view RUN`: a window on a trained run. It renders the deferred
//! composite through [`crate::embed::SceneRenderer`] into the frame's
//! command buffer on the window's own device and queue, with orbit, pan,
//! zoom and fly controls, the dataset's cameras, the layers `tgs render`
//! writes, the run's Stage I/II/III checkpoints and screenshots.

mod app;
pub mod controls;
mod gpu;
pub mod input;
pub mod motion;
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
    /// Marking the glass: outlined views that may leave a point out ([`crate::marks::Marks::tolerance`]).
    pub mark_tolerance: usize,
    /// Frames a second to keep while the camera moves ([`motion::Motion`]; 0: always full size).
    pub motion_fps: f32,
    pub device: DeviceSelector,
}

/// Open the window and run until it closes. Without a display this says
/// so and names `tgs render`, the headless way to the same images.
pub fn view(a: &ViewArgs) -> Result<()> {
    check_run(a)?;
    need_display(&a.run)?;
    app::run(a)
}

/// `tgs train --view`: train `t` on a thread of its own (its device from
/// `ctx`) while the window shows the model it trains, at most every
/// `every`, and after it, until closed. The training is the same as without
/// the window (the view only reads it). Closing the window leaves the
/// training running; Ctrl-C stops both.
pub fn train_live(
    t: &crate::train::run::TrainArgs,
    v: &ViewArgs,
    every: std::time::Duration,
    ctx: impl FnOnce() -> Result<std::sync::Arc<tgs_engine::Context>> + Send + 'static,
) -> Result<crate::train::run::Outcome> {
    need_display(&t.out)?;
    if let Some(s) = &v.script {
        input::read_script(s)?;
    }
    let el = app::event_loop()?;
    let proxy = el.create_proxy();
    let slot: app::Slot = Default::default();
    let open = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let handshake = std::sync::Arc::new(crate::train::live::Handshake::default());
    let send = {
        let (slot, proxy, open) = (slot.clone(), proxy.clone(), open.clone());
        std::sync::Arc::new(move |s: crate::train::live::Snapshot| {
            if open.load(std::sync::atomic::Ordering::Relaxed) {
                if let Ok(mut g) = slot.lock() {
                    *g = Some(s);
                }
                let _ = proxy.send_event(app::LiveEvent::Snapshot);
            }
        })
    };
    let mut args = t.clone();
    args.live = Some(crate::train::live::LiveSink { every, send, open: open.clone(), handshake: handshake.clone() });
    let trainer = std::thread::spawn(move || {
        let r = ctx().and_then(|c| crate::train::run::train(&c, &args));
        let _ = proxy.send_event(app::LiveEvent::Done { interrupted: r.as_ref().is_ok_and(|o| o.interrupted) });
        r
    });
    let shown = app::run_on(el, v, Some((slot, handshake.clone())));
    open.store(false, std::sync::atomic::Ordering::Relaxed);
    if let Err(e) = &shown {
        eprintln!("tgs: the view failed ({e:#}); training goes on without it");
    } else if !trainer.is_finished() {
        eprintln!("tgs: the window closed; training goes on (Ctrl-C stops it)");
    }
    let outcome = trainer.join().map_err(|_| anyhow::anyhow!("the training thread panicked"))?;
    if let Ok(o) = &outcome {
        let (sent, late, waited) = handshake.totals();
        let pc = 100.0 * waited / o.wall_s.max(1e-9);
        eprintln!(
            "tgs train --view: {sent} models sent to the window ({late} not drawn within the wait's limit); the training waited {waited:.1} s for it ({pc:.1}% of its {:.1} s)",
            o.wall_s
        );
    }
    outcome
}

fn check_run(a: &ViewArgs) -> Result<()> {
    // The run first: a missing or corrupt one gets the other commands' errors, display or not.
    if !a.run.is_dir() {
        bail!("{}: no such run directory", a.run.display());
    }
    crate::train::checkpoint::read(&a.run.join(crate::train::rundir::CHECKPOINT))?;
    if let Some(s) = &a.script {
        // Read before the window opens, so a bad script fails at once.
        input::read_script(s)?;
    }
    Ok(())
}

/// A display to open a window on, or the error naming the headless way.
fn need_display(run: &std::path::Path) -> Result<()> {
    let display = ["DISPLAY", "WAYLAND_DISPLAY"].iter().any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()));
    if !display {
        bail!(
            "no display to open a window on (neither DISPLAY nor WAYLAND_DISPLAY is set); `tgs render {}` writes the same images headless (or run under xvfb-run)",
            run.display()
        );
    }
    Ok(())
}
