//! Stage II's reflection layer for a renderer: the reflection set coloured
//! by the environment map, composited over the scattering colour.

use crate::train::stages::layer::{frame_for, RenderLayer};
use anyhow::Result;
use std::collections::HashMap;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::{Camera, EnvMap, Features, Frame, Fresnel, Gaussians, HostEnvMap, HostGaussians, Rasterizer, ReflectionShading, Splats};

pub struct EnvLayer {
    set: Gaussians,
    env: EnvMap,
    fresnel: Fresnel,
    shading: ReflectionShading,
    raster: Rasterizer,
    feat: Buffer<f32>,
    frames: HashMap<(u32, u32), Frame>,
}

impl EnvLayer {
    pub fn upload(ctx: &Arc<Context>, set: &HostGaussians, env: &HostEnvMap, fresnel: Fresnel) -> Result<EnvLayer> {
        let n = set.len().max(1);
        Ok(EnvLayer {
            set: Gaussians::upload(ctx, set)?,
            env: EnvMap::upload(ctx, env)?,
            shading: ReflectionShading::new(ctx)?,
            raster: Rasterizer::new(ctx, fresnel.channels(), Features::Plain)?,
            // The colour kernel writes every Gaussian's features before the rasterizer reads them.
            feat: Buffer::uninit(ctx, "embed.refl_features", fresnel.channels() as usize * n)?,
            fresnel,
            frames: HashMap::new(),
        })
    }
}

impl RenderLayer for EnvLayer {
    fn gaussians(&self) -> u32 {
        self.set.n
    }

    fn record(&mut self, rec: &mut Recorder, cam: &Camera, scat: &Buffer<f32>, out: &Buffer<f32>) -> Result<()> {
        let key = (cam.width, cam.height);
        if !self.frames.contains_key(&key) {
            self.frames.insert(key, frame_for(&self.raster, self.set.n, cam.width, cam.height)?);
        }
        let EnvLayer { set, env, fresnel, shading, raster, feat, frames } = self;
        let frame = &frames[&key];
        shading.record_color(rec, &tgs_pipelines::ColorInputs { g: set, env, cam, fresnel: *fresnel }, feat)?;
        raster.record_forward_with(rec, Splats::coloured(set, feat), cam, &vec![0.0; fresnel.channels() as usize], frame)?;
        shading.record_composite(rec, cam, *fresnel, &tgs_pipelines::reflection::CompositeInputs { scat, refl: &frame.out }, out)
    }

    fn complete(&mut self, cam: &Camera, whole: bool) -> Result<bool> {
        match self.frames.get_mut(&(cam.width, cam.height)) {
            Some(f) => Ok(whole & self.raster.fit(f)?),
            None => Ok(whole),
        }
    }
}
