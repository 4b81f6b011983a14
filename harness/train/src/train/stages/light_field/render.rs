//! Stage III's reflection layer for a renderer: the reflection set's
//! material, the light field Φ on the pixels that reflect (their count
//! stays on the device), composited over the scattering colour.

use crate::train::stages::layer::{frame_for, RenderLayer};
use anyhow::{bail, Result};
use std::collections::HashMap;
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::lightfield::{CompositeInputs, CHANNELS};
use tgs_pipelines::{Camera, Features, Frame, Gaussians, HostGaussians, LightFieldShading, Mlp, MlpScratch, MlpShape, Rasterizer, SampleScratch, ShadeParams, Splats};

/// Per view size: the reflection frame, the sample list and the network's scratch.
struct ViewBuffers {
    frame: Frame,
    samples: SampleScratch,
    scratch: MlpScratch,
}

pub struct LightFieldLayer {
    set: Gaussians,
    params: Buffer<f32>,
    shape: MlpShape,
    shade: ShadeParams,
    shading: LightFieldShading,
    mlp: Mlp,
    raster: Rasterizer,
    feat: Buffer<f32>,
    views: HashMap<(u32, u32), ViewBuffers>,
    last_samples: Option<u32>,
}

impl LightFieldLayer {
    pub fn upload(ctx: &Arc<Context>, set: &HostGaussians, shape: MlpShape, params: &[f32], shade: ShadeParams) -> Result<LightFieldLayer> {
        let n = set.len().max(1);
        Ok(LightFieldLayer {
            set: Gaussians::upload(ctx, set)?,
            params: Buffer::from_slice(ctx, "embed.mlp_params", params)?,
            shape,
            shade,
            shading: LightFieldShading::new(ctx)?,
            mlp: Mlp::new(ctx)?,
            raster: Rasterizer::new(ctx, CHANNELS, Features::Plain)?,
            // The material kernel writes every Gaussian's features first.
            feat: Buffer::uninit(ctx, "embed.lf_features", CHANNELS as usize * n)?,
            views: HashMap::new(),
            last_samples: None,
        })
    }
}

impl RenderLayer for LightFieldLayer {
    fn gaussians(&self) -> u32 {
        self.set.n
    }

    fn record(&mut self, rec: &mut Recorder, cam: &Camera, scat: &Buffer<f32>, out: &Buffer<f32>) -> Result<()> {
        let (w, h) = (cam.width, cam.height);
        if !self.views.contains_key(&(w, h)) {
            let cap = (w * h).min(self.mlp.max_capacity(&self.shape));
            let v = ViewBuffers { frame: frame_for(&self.raster, self.set.n, w, h)?, samples: self.shading.sample_scratch(w, h)?, scratch: self.mlp.scratch(self.shape, cap)? };
            self.views.insert((w, h), v);
        }
        let LightFieldLayer { set, params, shade, shading, mlp, raster, feat, views, .. } = self;
        let ViewBuffers { frame, samples, scratch } = &views[&(w, h)];
        let sc = rec.begin_scope("view.lf.material");
        shading.record_material(rec, &set.features, set.n, feat)?;
        rec.end_scope(sc);
        let sc = rec.begin_scope("view.lf.raster");
        raster.record_forward_with(rec, Splats::coloured(set, feat), cam, &[0.0; CHANNELS as usize], frame)?;
        rec.end_scope(sc);
        let sc = rec.begin_scope("view.lf.samples");
        shading.record_samples(rec, cam, shade, &frame.out, samples, &scratch.samples)?;
        rec.end_scope(sc);
        let sc = rec.begin_scope("view.lf.mlp");
        mlp.record_forward_counted(rec, params, &samples.count, scratch)?;
        rec.end_scope(sc);
        let sc = rec.begin_scope("view.lf.composite");
        let done = shading.record_composite(rec, cam, shade, &CompositeInputs { scat, refl: &frame.out, samples, phi: &scratch.out }, out);
        rec.end_scope(sc);
        done
    }

    fn complete(&mut self, cam: &Camera, whole: bool) -> Result<bool> {
        let Some(v) = self.views.get_mut(&(cam.width, cam.height)) else { return Ok(whole) };
        let whole = whole & self.raster.fit(&mut v.frame)?;
        let count = v.samples.count.download()?[0];
        self.last_samples = Some(count);
        if whole && count > v.scratch.capacity() {
            bail!(
                "{count} pixels of this {}x{} view reflect (R > {}); the light field evaluates at most {} on this device, so {} pixels show the scattering colour alone",
                cam.width,
                cam.height,
                self.shade.threshold,
                v.scratch.capacity(),
                count - v.scratch.capacity()
            );
        }
        Ok(whole)
    }

    fn last_samples(&self) -> Option<u32> {
        self.last_samples
    }
}
