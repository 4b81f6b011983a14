//! Frame time of the viewer's final image without a window: what `tgs view`
//! records each frame (the run's composite through `SceneRenderer`, packed
//! into pixels) on an orbit around the scene, submitted and waited for.
//! For devices that have no display to open a window on (a GPU server);
//! `perf/view/bench.sh` times the window itself, swapchain included.

use crate::view::controls::Nav;
use crate::view::scene::Scene;
use anyhow::{ensure, Context as _, Result};
use serde::Serialize;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;
use tgs_engine::{summarize, Buffer, Context, Recorder};
use tgs_pipelines::PixelOrder;

#[derive(Clone, Debug, Serialize)]
pub struct ViewBench {
    pub device: String,
    pub run: String,
    /// The checkpoint's stage (I, II or III).
    pub stage: String,
    pub width: u32,
    pub height: u32,
    pub frames: u32,
    pub gaussians: (usize, usize),
    /// Mean and best record-to-completion time of a frame, ms (the first, which grows the buffers, excluded).
    pub mean_ms: f64,
    pub best_ms: f64,
    pub fps: f64,
    /// Stage III: the pixels Φ ran on in the last frame.
    pub phi_pixels: Option<u32>,
    /// With `--profile`: GPU ms a frame per kernel scope (nested scopes
    /// overlap: `view.reflection` holds the `view.lf.*` below it).
    pub scopes: Vec<(String, f64)>,
}

/// Orbit `frames` frames (3 pixels of drag each, as `perf/view/bench.sh`)
/// from the run's first test camera at `size`; `profile` times each
/// kernel scope with timestamp queries (the frame times then include them).
pub fn view(ctx: &Arc<Context>, run: &Path, size: (u32, u32), frames: u32, profile: bool) -> Result<ViewBench> {
    let (width, height) = size;
    ensure!(width >= 1 && height >= 1 && frames >= 1, "bench view: the size and the frame count must be at least 1");
    let mut scene = Scene::open(ctx, run).with_context(|| format!("opening {}", run.display()))?;
    let mut nav = Nav::at(&scene.dataset_camera().1, scene.target, scene.up);
    let pixels = Buffer::<u32>::uninit(ctx, "bench.view.pixels", (width * height) as usize)?;
    let mut times = Vec::with_capacity(frames as usize);
    let mut timings = Vec::new();
    for f in 0..=frames {
        nav.orbit(3.0, 0.0);
        let cam = nav.camera(width, height);
        let t0 = Instant::now();
        // A frame that grew the renderer's buffers is drawn again, as the window does.
        for tries in 0.. {
            ensure!(tries < 4, "bench view: frame {f} never fitted the renderer's buffers");
            let mut rec = Recorder::profiled_if(ctx, profile)?;
            let sc = rec.begin_scope("view.frame");
            scene.record_final(&mut rec, &cam, PixelOrder::Rgba, &pixels)?;
            rec.end_scope(sc);
            let t = rec.submit_and_wait()?;
            if scene.complete(&cam)? {
                if f > 0 {
                    timings.extend(t);
                }
                break;
            }
        }
        if f > 0 {
            times.push(1e3 * t0.elapsed().as_secs_f64());
        }
    }
    let mean_ms = times.iter().sum::<f64>() / times.len() as f64;
    Ok(ViewBench {
        device: ctx.caps().describe(),
        run: run.display().to_string(),
        stage: scene.stage().to_string(),
        width,
        height,
        frames,
        gaussians: scene.counts,
        mean_ms,
        best_ms: times.iter().copied().fold(f64::INFINITY, f64::min),
        fps: 1e3 / mean_ms,
        phi_pixels: scene.phi_pixels(),
        scopes: summarize(&timings).into_iter().map(|s| (s.name, s.total_ms / frames as f64)).collect(),
    })
}

pub fn print_view(b: &ViewBench) {
    println!("device: {}", b.device);
    println!(
        "view {} (Stage {}, {} + {} Gaussians) at {}x{}: {:.2} ms/frame mean, {:.2} best, {:.1} frames/s over {} frames (no window: render and pack, submitted and waited for)",
        b.run, b.stage, b.gaussians.0, b.gaussians.1, b.width, b.height, b.mean_ms, b.best_ms, b.fps, b.frames
    );
    if let Some(n) = b.phi_pixels {
        println!("  the light field ran on {n} of {} pixels in the last frame", b.width * b.height);
    }
    for (name, ms) in &b.scopes {
        println!("  {name:<24} {ms:8.3} ms/frame");
    }
}
