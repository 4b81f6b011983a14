//! Stage III as the trainer drives it: the transition from Stage II (the
//! reflection set moves to a light-field model with a fresh network) and
//! one iteration of the light field.

use super::model::{normalization_box, LightFieldModel, LightFieldStepInput};
use crate::train::schedule::Stage;
use crate::train::trainer::{StepReport, Trainer};
use anyhow::{Context as _, Result};

impl Trainer {
    /// Whether the next iteration starts Stage III (call
    /// [`Trainer::begin_light_field`] first).
    pub fn at_light_field_start(&self) -> bool {
        self.light_field.is_none() && matches!(self.schedule.at(self.iteration + 1), Some((Stage::LightField, _)))
    }

    /// Between Stage II and III: the reflection set (with its Adam moments)
    /// moves to a light-field model with a fresh network; the environment
    /// map is dropped. Positions are normalized by the reflection set's box.
    pub fn begin_light_field(&mut self) -> Result<()> {
        let refl = self.reflection.take().context("Stage III starts from Stage II's reflection set, and there is none")?;
        let set = refl.into_set();
        let (centre, half_extent) = normalization_box(&set.params.means.download()?);
        let lf = &self.cfg.light_field;
        let shade = tgs_pipelines::ShadeParams { centre, half_extent, threshold: lf.threshold, schlick: lf.schlick() };
        let net = LightFieldModel::init_net(&self.ctx, lf.shape()?, self.cfg.seed ^ 0x4c46)?;
        self.light_field = Some(LightFieldModel::new(&self.ctx, set, net, shade, self.cfg.adam_eps)?);
        // Stage III renders the scattering colour itself, or caches it
        // again when Stage II changed it.
        if lf.train_scattering || self.cfg.reflection.train_scattering {
            self.scat_cache.clear();
        }
        Ok(())
    }

    pub(crate) fn step_light_field(&mut self, it: u32, stage_it: u32, profile: bool) -> Result<StepReport> {
        let frozen = !self.cfg.light_field.train_scattering;
        if frozen {
            self.ensure_scat_cache()?;
        }
        let view = self.next_view();
        let cam = self.cameras[view as usize];
        let sh = self.sh_degree(self.cfg.iterations);
        let model = self.light_field.as_mut().context("Stage III has not begun (Trainer::begin_light_field)")?;
        let input = LightFieldStepInput {
            iteration: stage_it,
            global_iteration: it,
            camera: &cam,
            target: &self.targets[view as usize],
            scat: if frozen { Some(&self.scat_cache[view as usize]) } else { None },
            sh_degree: sh,
            background: self.background,
            // Positions at Stage I's final rate (method-notes §3.7).
            lr_means: self.cfg.lr_means_final * self.extent,
            profile,
        };
        let out = model.step(&self.cfg, &mut self.scattering, &input)?;
        self.iteration = it;
        Ok(StepReport {
            iteration: it,
            stage: Stage::LightField,
            view,
            loss: out.loss,
            values: out.values,
            gaussians: model.set.len(),
            densified: None,
            opacity_reset: false,
            timings: out.timings,
        })
    }
}
