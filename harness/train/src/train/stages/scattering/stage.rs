//! Stage I as the trainer drives it: one iteration of the scattering set
//! (the opacity reset due after the previous one, then the step).

use super::model::{ScatteringModel, StepInput, StepOutput};
use crate::train::config::TrainConfig;
use crate::train::stages::views::Views;
use anyhow::Result;

/// Position learning rate at Stage I iteration `it`: log-linear over the
/// stage, times the scene extent.
pub fn lr_means(cfg: &TrainConfig, extent: f32, it: u32) -> f32 {
    (crate::train::log_lerp(cfg.lr_means, cfg.lr_means_final, it as f64 / cfg.iterations.max(1) as f64) * extent as f64) as f32
}

/// Iteration `it` on training view `view`; also whether the opacity reset
/// ran before it.
pub fn iterate(model: &mut ScatteringModel, cfg: &TrainConfig, views: &Views, it: u32, view: u32, profile: bool) -> Result<(StepOutput, bool)> {
    // The reset that follows iteration it-1 runs here, at the start of
    // the next iteration (the same order of operations as 2DGS), so that
    // a test evaluation or checkpoint at it-1 sees the trained state.
    let reset = cfg.opacity_reset_after(it - 1, views.background == [1.0; 3]);
    if reset {
        model.reset_opacity()?;
    }
    let cam = views.cameras[view as usize];
    let input = StepInput {
        iteration: it,
        camera: &cam,
        target: &views.targets[view as usize],
        sh_degree: cfg.sh_degree_at(it),
        lr_means: lr_means(cfg, views.extent, it),
        background: views.background,
        extent: views.extent,
        profile,
    };
    Ok((model.step(cfg, &input)?, reset))
}
