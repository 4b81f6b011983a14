//! The training views as every stage sees them: the device, the cameras,
//! the target images on the device, the background, the glass masks the
//! dataset gives, and the scene's frame
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
    /// Each view's glass mask where the dataset gives one (`mask_path`;
    /// `reflection.dataset_masks`), row-major, true on the glass.
    pub masks: Vec<Option<Vec<bool>>>,
    /// The camera sphere: its radius (the scene extent; positions' learning
    /// rates scale with it) and its centre (the cameras' mean).
    pub extent: f32,
    pub centre: [f32; 3],
}

impl Views {
    /// Whether training view `i` is a validation view: every `every`-th
    /// (views every-1, 2 every-1, ...); none with `every` 0.
    pub fn is_validation(i: usize, every: u32) -> bool {
        every > 0 && i % every as usize == every as usize - 1
    }

    /// Drop the validation views (the scene's frame stays that of all
    /// the training cameras).
    pub fn hold_out(&mut self, every: u32) {
        fn keep<T>(v: &mut Vec<T>, every: u32) {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                !Views::is_validation(i - 1, every)
            });
        }
        keep(&mut self.cameras, every);
        keep(&mut self.targets, every);
        keep(&mut self.masks, every);
    }
}
