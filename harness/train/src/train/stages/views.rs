//! The training views as every stage sees them: the device, the cameras,
//! the target images on the device, the background, and the scene's frame
//! (the camera sphere).

use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::Camera;

pub struct Views {
    pub ctx: Arc<Context>,
    pub cameras: Vec<Camera>,
    /// Each view's target image (planar RGB), on the device.
    pub targets: Vec<Buffer<f32>>,
    pub background: [f32; 3],
    /// The camera sphere: its radius (the scene extent; positions' learning
    /// rates scale with it) and its centre (the cameras' mean).
    pub extent: f32,
    pub centre: [f32; 3],
}
