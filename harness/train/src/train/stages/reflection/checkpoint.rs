//! Stage II's part of the checkpoint: after the scattering set's arrays,
//! the reflection set's (prefixed `refl.`, `TrainableSet::layout` order),
//! then the cube map's texels and Adam moments, and its frozen depth when
//! it has one; the header records the set's size, the map's resolution
//! and the decision that started the stage.

use super::{ReflDecision, ReflectionModel};
use crate::train::arrays::{check_arrays, host_set, upload_set};
use crate::train::config::TrainConfig;
use anyhow::Result;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use tgs_engine::{Buffer, Context};
use tgs_pipelines::reflection::MATERIAL;
use tgs_pipelines::TrainableSet;

const ENV_ARRAYS: [&str; 3] = ["env.param", "env.adam_m", "env.adam_v"];
/// The frozen depth of a depth-mapped cube map (env_init = "scene-depth"),
/// after [`ENV_ARRAYS`] when the map has one.
const ENV_DEPTH: &str = "env.depth";

#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ReflHeader {
    pub n: u32,
    pub env_res: u32,
    pub decision: ReflDecision,
    pub arrays: Vec<(String, usize)>,
}

impl ReflHeader {
    /// The arrays this state must hold (the reflection set's, then the cube
    /// map's texels and Adam moments), checked against `arrays`; returns the
    /// index of the texels.
    pub(crate) fn check(&self, arrays: &[Vec<f32>]) -> Result<usize> {
        let layout = set_layout(self.n);
        let env_len = 18 * self.env_res as usize * self.env_res as usize;
        let k = layout.len();
        let mut want: Vec<(String, usize)> = layout.into_iter().chain(ENV_ARRAYS.map(|n| (n.to_string(), env_len))).collect();
        if self.has_depth() {
            want.push((ENV_DEPTH.to_string(), env_len / 3));
        }
        check_arrays(&want, &self.arrays, arrays)?;
        Ok(k)
    }

    fn has_depth(&self) -> bool {
        self.arrays.last().is_some_and(|(name, _)| name == ENV_DEPTH)
    }

    /// The cube map from the arrays [`ReflHeader::check`] passed (`k`: the
    /// index of its texels).
    pub(crate) fn env(&self, arrays: &[Vec<f32>], k: usize) -> tgs_pipelines::HostEnvMap {
        let depth = self.has_depth().then(|| arrays[k + ENV_ARRAYS.len()].clone());
        tgs_pipelines::HostEnvMap { res: self.env_res, raw: arrays[k].clone(), proxy: self.decision.proxy(), depth }
    }

    /// Stage II's header, its arrays' buffers and lengths appended to `bufs`.
    pub(crate) fn save<'a>(m: &'a ReflectionModel, d: &ReflDecision, bufs: &mut Vec<(&'a Buffer<f32>, usize)>) -> ReflHeader {
        let mut names = Vec::new();
        push_set(&m.set, &mut names, bufs);
        for (name, buf) in m.env.arrays() {
            names.push((name.to_string(), m.env.len()));
            bufs.push((buf, m.env.len()));
        }
        if let Some(d) = &m.env.depth {
            names.push((ENV_DEPTH.to_string(), m.env.texels() as usize));
            bufs.push((d, m.env.texels() as usize));
        }
        ReflHeader { n: m.set.len(), env_res: m.env.res, decision: d.clone(), arrays: names }
    }

    /// Stage II's model from the arrays after the scattering set's (its
    /// decision is this header's).
    pub(crate) fn restore(&self, ctx: &Arc<Context>, cfg: &TrainConfig, arrays: Vec<Vec<f32>>) -> Result<ReflectionModel> {
        let k = self.check(&arrays)?;
        let g = host_set(MATERIAL, 1, &arrays);
        let env = self.env(&arrays, k);
        let m = ReflectionModel::new(ctx, &g, &env, cfg.reflection.fresnel.pipeline(), cfg.adam_eps)?;
        upload_set(&m.set, &arrays)?;
        m.env.m.upload(&arrays[k + 1])?;
        m.env.v.upload(&arrays[k + 2])?;
        Ok(m)
    }
}

/// The reflection set's arrays as a checkpoint names and sizes them.
pub(crate) fn set_layout(n: u32) -> Vec<(String, usize)> {
    TrainableSet::layout(MATERIAL as usize).into_iter().map(|(name, w)| (format!("refl.{name}"), w * n as usize)).collect()
}

/// The reflection set's arrays (names prefixed `refl.`, lengths) and
/// buffers, in `TrainableSet::layout` order.
pub(crate) fn push_set<'a>(set: &'a TrainableSet, names: &mut Vec<(String, usize)>, bufs: &mut Vec<(&'a tgs_engine::Buffer<f32>, usize)>) {
    let n = set.len() as usize;
    for (name, buf, w) in set.arrays() {
        names.push((format!("refl.{name}"), w * n));
        bufs.push((buf, w * n));
    }
}

/// The reflection set of a Stage II or III state (its first arrays) on
/// the host, checked, for a renderer.
pub(crate) fn host_reflection_set(arrays: &[Vec<f32>]) -> Result<tgs_pipelines::HostGaussians> {
    let set = host_set(MATERIAL, 1, arrays);
    set.validate()?;
    Ok(set)
}

/// The reflection set of a Stage II or III state (its first arrays).
pub(crate) fn reflection_set(ctx: &Arc<Context>, arrays: &[Vec<f32>]) -> Result<TrainableSet> {
    let set = TrainableSet::new(ctx, &host_set(MATERIAL, 1, arrays))?;
    upload_set(&set, arrays)?;
    Ok(set)
}
