//! A later stage's reflection layer as a renderer draws it from a
//! checkpoint (`tgs::embed::SceneRenderer`, `tgs view`): the stage's
//! parameters on a device, recorded after the scattering set into a
//! host's command buffer. Each stage's `render.rs` implements it (a cube
//! map, the light field); the renderer names no stage.

use anyhow::Result;
use tgs_engine::{Buffer, Recorder};
use tgs_pipelines::{Camera, Frame, Rasterizer};

/// A stage's reflection layer on a device.
pub trait RenderLayer: Send {
    /// Gaussians in its reflection set.
    fn gaussians(&self) -> u32;
    /// Record the composite of `cam` over the scattering layer's colour
    /// `scat` (planes) into `out` (planes, every pixel written).
    fn record(&mut self, rec: &mut Recorder, cam: &Camera, scat: &Buffer<f32>, out: &Buffer<f32>) -> Result<()>;
    /// After the submission of [`RenderLayer::record`]: `whole` and the
    /// layer's own buffers fitted (too small ones are grown, and the view
    /// is recorded again).
    fn complete(&mut self, cam: &Camera, whole: bool) -> Result<bool>;
    /// Pixels the layer's network ran on in the last completed view, where it has one.
    fn last_samples(&self) -> Option<u32> {
        None
    }
}

/// A frame for a set of `n` Gaussians at `w` x `h` (room for 1,024 more).
pub fn frame_for(raster: &Rasterizer, n: u32, w: u32, h: u32) -> Result<Frame> {
    let max_g = n + 1024;
    raster.frame(w, h, max_g, raster.initial_capacity(max_g))
}
