//! Stage III as the trainer drives it: the transition from Stage II (the
//! reflection set moves to a light-field model with a fresh network) and
//! one iteration of the light field.

use super::model::{LightFieldModel, LightFieldStepInput};
use crate::train::config::TrainConfig;
use crate::train::schedule::Stage;
use crate::train::stages::reflection::bounds::normalization_box;
use crate::train::stages::rendered::ReflRendered;
use crate::train::stages::scattering::StepOutput;
use crate::train::stages::shared::{Iteration, LaterStage, Shared};
use anyhow::{Context as _, Result};
use std::any::Any;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::{Camera, TrainableSet};

/// Between Stage II and III: the reflection set `set` (with its Adam
/// moments) moves to a light-field model with a fresh network; Stage II's
/// environment map is dropped. Positions are normalized by the reflection
/// set's box.
pub fn begin(cfg: &TrainConfig, ctx: &Arc<Context>, set: TrainableSet) -> Result<LightFieldModel> {
    let (centre, half_extent) = normalization_box(&set.params.means.download()?);
    let lf = &cfg.light_field;
    let shade = tgs_pipelines::ShadeParams { centre, half_extent, threshold: lf.threshold, schlick: lf.schlick() };
    let net = LightFieldModel::init_net(ctx, lf.shape()?, cfg.seed ^ 0x4c46)?;
    LightFieldModel::new(ctx, set, net, shade, cfg.adam_eps)
}

impl LaterStage for LightFieldModel {
    fn stage(&self) -> Stage {
        Stage::LightField
    }

    fn iterate(&mut self, s: Shared<'_>, x: &Iteration) -> Result<StepOutput> {
        let (cfg, v) = (s.cfg, s.views);
        let frozen = !cfg.light_field.train_scattering;
        let sh = cfg.sh_degree_at(cfg.iterations);
        if frozen {
            s.cache.ensure(v, s.scattering, sh)?;
        }
        let cam = v.cameras[x.view as usize];
        let input = LightFieldStepInput {
            iteration: x.stage,
            global_iteration: x.global,
            camera: &cam,
            target: &v.targets[x.view as usize],
            scat: if frozen { Some(s.cache.get(x.view as usize).context("the scattering colour cache is missing")?) } else { None },
            sh_degree: sh,
            background: v.background,
            // Positions at Stage I's final rate (method-notes §3.7).
            lr_means: cfg.lr_means_final * v.extent,
            profile: x.profile,
        };
        self.step(cfg, s.scattering, &input)
    }

    fn render(&mut self, cam: &Camera, scat: &Buffer<f32>) -> Result<ReflRendered> {
        LightFieldModel::render(self, cam, scat)
    }

    fn set(&self) -> &TrainableSet {
        &self.set
    }

    fn write_outputs(&self, out: &Path) -> Result<()> {
        LightFieldModel::write_outputs(self, out)
    }

    fn into_set(self: Box<Self>) -> TrainableSet {
        self.set
    }

    fn take_coverage(&mut self) -> Option<f64> {
        LightFieldModel::take_coverage(self)
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
