//! Stage I as the trainer drives it: one iteration of the scattering set
//! (the opacity reset due after the previous one, the next view, the step).

use super::model::StepInput;
use crate::train::schedule::Stage;
use crate::train::trainer::{StepReport, Trainer};
use anyhow::Result;

impl Trainer {
    pub(crate) fn step_scattering(&mut self, it: u32, stage: Stage, profile: bool) -> Result<StepReport> {
        // The reset that follows iteration it-1 runs here, at the start of
        // the next iteration (the same order of operations as 2DGS), so that
        // a test evaluation or checkpoint at it-1 sees the trained state.
        let reset = self.cfg.opacity_reset_after(it - 1, self.background == [1.0; 3]);
        if reset {
            self.scattering.reset_opacity()?;
        }
        let view = self.next_view();
        let cam = self.cameras[view as usize];
        let input = StepInput {
            iteration: it,
            camera: &cam,
            target: &self.targets[view as usize],
            sh_degree: self.sh_degree(it),
            lr_means: self.lr_means(it),
            background: self.background,
            extent: self.extent,
            profile,
        };
        let out = self.scattering.step(&self.cfg, &input)?;
        self.iteration = it;
        Ok(StepReport {
            iteration: it,
            stage,
            view,
            loss: out.loss,
            values: out.values,
            gaussians: self.scattering.set.len(),
            densified: out.densified,
            opacity_reset: reset,
            timings: out.timings,
        })
    }
}
