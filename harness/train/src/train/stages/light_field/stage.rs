//! Stage III as the trainer drives it: the transition from Stage II (the
//! reflection set moves to a light-field model with a fresh network) and
//! one iteration of the light field.

use super::checkpoint::LightFieldHeader;
use super::model::{LightFieldModel, LightFieldStepInput};
use crate::train::config::TrainConfig;
use crate::train::stage::Stage;
use crate::train::stages::kept_views::KeepAs;
use crate::train::stages::kind::{parse, Begun, LaterKind, Transition};
use crate::train::stages::layer::RenderLayer;
use crate::train::stages::reflection::bounds::normalization_box;
use crate::train::stages::reflection::checkpoint::host_reflection_set;
use crate::train::stages::reflection::ReflDecision;
use crate::train::stages::rendered::ReflRendered;
use crate::train::stages::scattering::StepOutput;
use crate::train::stages::shared::{Iteration, LaterStage, Shared};
use anyhow::{bail, Context as _, Result};
use std::any::Any;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::{Camera, TrainableSet};

/// Stage III.
pub const STAGE: Stage = Stage("III");

/// Stage III as the schedule and the checkpoint know it.
pub struct Kind;

impl LaterKind for Kind {
    fn stage(&self) -> Stage {
        STAGE
    }

    fn key(&self) -> &'static str {
        "light_field"
    }

    fn iterations(&self, cfg: &TrainConfig) -> u32 {
        cfg.light_field.iterations
    }

    fn resumable(&self) -> &'static [&'static str] {
        &["light_field.iterations"]
    }

    /// Stage III runs again after a reseeded Stage II (`reflection.reseed`).
    fn frees_earlier_settings(&self) -> &'static [&'static str] {
        &["reflection.reseed"]
    }

    fn trains_scattering(&self, cfg: &TrainConfig) -> bool {
        cfg.light_field.train_scattering
    }

    /// From Stage II's model ([`begin`]); the frozen scattering colours
    /// are cached again when Stage II or III trains the scattering set.
    fn begin(&self, t: Transition<'_>) -> Result<Begun> {
        let Transition { shared, previous, label, .. } = t;
        let prev = match previous {
            Some(m) if m.stage() == crate::train::stages::reflection::stage::STAGE => m,
            _ => bail!("Stage III starts from Stage II's reflection set, and there is none"),
        };
        let m = begin(shared.cfg, &shared.views.ctx, prev.into_set())?;
        // Stage III renders the scattering colour itself, or caches it
        // again when Stage II changed it.
        if shared.cfg.light_field.train_scattering || shared.cfg.reflection.train_scattering {
            shared.cache.clear();
        }
        let message = m.start_message(&label, &shared.cfg.light_field);
        Ok(Begun { model: Some(Box::new(m)), runs: true, message, event: serde_json::Map::new() })
    }

    fn restore(&self, header: &serde_json::Value, ctx: &Arc<Context>, cfg: &TrainConfig, arrays: Vec<Vec<f32>>) -> Result<(Box<dyn LaterStage>, ReflDecision)> {
        let h: LightFieldHeader = parse(self, header)?;
        Ok((Box::new(h.restore(ctx, cfg, arrays)?), h.decision))
    }

    fn render_layer(&self, header: &serde_json::Value, _cfg: &TrainConfig, arrays: Vec<Vec<f32>>, ctx: &Arc<Context>) -> Result<Box<dyn RenderLayer>> {
        let h: LightFieldHeader = parse(self, header)?;
        let shape = h.shape()?;
        h.check(&shape, &arrays)?;
        let set = host_reflection_set(&arrays)?;
        let params = &arrays[arrays.len() - 3];
        Ok(Box::new(super::render::LightFieldLayer::upload(ctx, &set, shape, params, h.shade())?))
    }

    fn files(&self) -> &'static [&'static str] {
        &["reflection.ply", "light_field.safetensors"]
    }
}

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
        STAGE
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
            keep: KeepAs { view: x.view, budget_mib: cfg.light_field.kept_binning_mib },
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

    fn save_state<'a>(&'a self, d: &ReflDecision, bufs: &mut Vec<(&'a Buffer<f32>, usize)>) -> Result<serde_json::Value> {
        Ok(serde_json::to_value(LightFieldHeader::save(self, d, bufs))?)
    }

    fn take_coverage(&mut self) -> Option<f64> {
        LightFieldModel::take_coverage(self)
    }

    fn as_any(&self) -> &dyn Any {
        self
    }
}
