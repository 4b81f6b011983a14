//! Stage III's part of the checkpoint: after the scattering set's arrays,
//! the reflection set's (as Stage II writes them), then the network's
//! parameters and Adam moments; the header records the network's shape,
//! the shading box and the Stage II decision.

use super::{LightFieldModel, MlpParams};
use crate::train::arrays::check_arrays;
use crate::train::config::TrainConfig;
use crate::train::stages::reflection::checkpoint::{push_set, reflection_set, set_layout};
use crate::train::stages::reflection::ReflDecision;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use tgs_engine::{Buffer, Context};

const MLP_ARRAYS: [&str; 3] = ["mlp.param", "mlp.adam_m", "mlp.adam_v"];

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct LightFieldHeader {
    pub n: u32,
    /// depth, width, skip, levels_x, levels_w.
    pub shape: [u32; 5],
    pub centre: [f32; 3],
    pub half_extent: [f32; 3],
    pub threshold: f32,
    pub schlick: bool,
    pub decision: ReflDecision,
    pub arrays: Vec<(String, usize)>,
}

impl LightFieldHeader {
    pub fn shape(&self) -> Result<tgs_pipelines::MlpShape> {
        let [depth, width, skip, levels_x, levels_w] = self.shape;
        let shape = tgs_pipelines::MlpShape { depth, width, skip, levels_x, levels_w };
        shape.validate()?;
        Ok(shape)
    }
    pub fn shade(&self) -> tgs_pipelines::ShadeParams {
        tgs_pipelines::ShadeParams { centre: self.centre, half_extent: self.half_extent, threshold: self.threshold, schlick: self.schlick }
    }
    /// The arrays this state must hold (the reflection set's, then the
    /// network's parameters and Adam moments), checked against `arrays`.
    pub(crate) fn check(&self, shape: &tgs_pipelines::MlpShape, arrays: &[Vec<f32>]) -> Result<()> {
        let p = shape.params() as usize;
        let want: Vec<(String, usize)> = set_layout(self.n).into_iter().chain(MLP_ARRAYS.map(|n| (n.to_string(), p))).collect();
        check_arrays(&want, &self.arrays, arrays)
    }

    /// Stage III's header, its arrays' buffers and lengths appended to `bufs`.
    pub(crate) fn save<'a>(m: &'a LightFieldModel, d: &ReflDecision, bufs: &mut Vec<(&'a Buffer<f32>, usize)>) -> LightFieldHeader {
        let mut names = Vec::new();
        push_set(&m.set, &mut names, bufs);
        let p = m.net.shape.params() as usize;
        for (name, buf) in MLP_ARRAYS.iter().zip([&m.net.params, &m.net.m, &m.net.v]) {
            names.push((name.to_string(), p));
            bufs.push((buf, p));
        }
        let s = m.net.shape;
        LightFieldHeader {
            n: m.set.len(),
            shape: [s.depth, s.width, s.skip, s.levels_x, s.levels_w],
            centre: m.shade.centre,
            half_extent: m.shade.half_extent,
            threshold: m.shade.threshold,
            schlick: m.shade.schlick,
            decision: d.clone(),
            arrays: names,
        }
    }

    /// Stage III's model from the arrays after the scattering set's (its
    /// decision is this header's).
    pub(crate) fn restore(&self, ctx: &Arc<Context>, cfg: &TrainConfig, arrays: Vec<Vec<f32>>) -> Result<LightFieldModel> {
        let shape = self.shape()?;
        self.check(&shape, &arrays)?;
        let k = arrays.len() - 3;
        let set = reflection_set(ctx, &arrays)?;
        let net = MlpParams::new(ctx, shape, &arrays[k], &arrays[k + 1], &arrays[k + 2])?;
        LightFieldModel::new(ctx, set, net, self.shade(), cfg.adam_eps)
    }
}
