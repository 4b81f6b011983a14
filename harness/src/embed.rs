//! Rendering a trained run inside a host application's Vulkan renderer.
//!
//! [`SceneRenderer::load`] reads a run's checkpoint (no dataset, no
//! training state beyond the parameters) onto a [`Context`], typically one
//! that adopted the host's device and queue ([`Context::adopt`]).
//! [`SceneRenderer::record`] records the deferred render of a camera into a
//! [`Recorder`], typically one recording into the host's own command buffer
//! ([`Recorder::record_into`]), and copies the colour (3 planes of f32, R
//! then G then B, row-major) into a buffer the host owns. Nothing is read
//! back between the kernels: the light field's sample count stays on the
//! GPU and the MLP runs only on the pixels that reflect.
//!
//! After the host's submission completes, [`SceneRenderer::complete`] says
//! whether the frame was whole: the first view of a size (or one with many
//! more splat-tile intersections than before) can outgrow the intersection
//! buffers; they are grown then, and the host records the view again.
//!
//! What is rendered is what `tgs render` writes: the scattering set alone
//! after Stage I, the composite with the environment map after Stage II, the
//! composite with the light field after Stage III.

use crate::train::checkpoint;
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, BufferBinding, Context, Recorder};
use tgs_pipelines::{
    Camera, EnvMap, Features, Frame, Fresnel, Gaussians, LightFieldShading, Mlp, MlpScratch, MlpShape, Plane, Rasterizer, ReflectionShading, SampleScratch, ShadeParams, Splats,
};

/// The reflection layer of a run past Stage I.
enum Layer {
    /// Stage II: reflection set coloured by the environment map.
    Env { set: Gaussians, env: EnvMap, fresnel: Fresnel, shading: ReflectionShading, raster: Rasterizer, feat: Buffer<f32> },
    /// Stage III: reflection set's material, Φ on the reflecting pixels.
    Light { set: Gaussians, params: Buffer<f32>, shape: MlpShape, shade: ShadeParams, shading: LightFieldShading, mlp: Mlp, raster: Rasterizer, feat: Buffer<f32> },
}

/// Per image size: both sets' frames, the sample list, the composite.
struct View {
    scat: Frame,
    refl: Option<Frame>,
    samples: Option<(SampleScratch, MlpScratch)>,
    composite: Option<Buffer<f32>>,
}

pub struct SceneRenderer {
    ctx: Arc<Context>,
    scat: Gaussians,
    sh_degree: u32,
    background: [f32; 3],
    raster: Rasterizer,
    layer: Option<Layer>,
    views: HashMap<(u32, u32), View>,
    /// The stage the run finished ("I", "II" or "III").
    pub stage: &'static str,
    /// Pixels the light field was evaluated on in the last completed view (Stage III).
    pub last_samples: Option<u32>,
}

fn frame_for(raster: &Rasterizer, n: u32, w: u32, h: u32) -> Result<Frame> {
    let max_g = n + 1024;
    raster.frame(w, h, max_g, raster.initial_capacity(max_g))
}

impl SceneRenderer {
    /// Load `run`'s checkpoint (`RUN/checkpoint.bin`; a run directory or the
    /// file itself).
    pub fn load(ctx: &Arc<Context>, run: &Path) -> Result<SceneRenderer> {
        let path = if run.is_dir() { run.join(crate::train::run::CHECKPOINT) } else { run.to_path_buf() };
        let (h, arrays) = checkpoint::read(&path)?;
        Self::from_checkpoint(ctx, &h, arrays).map_err(|e| e.context(format!("{}: cannot render this checkpoint", path.display())))
    }

    /// From a checkpoint's header and arrays as [`checkpoint::read`] (or
    /// [`checkpoint::snapshot`], for a run still training) returns them.
    pub fn from_checkpoint(ctx: &Arc<Context>, h: &checkpoint::Header, arrays: Vec<Vec<f32>>) -> Result<SceneRenderer> {
        let state = checkpoint::render_state(h, arrays)?;
        let cfg = &h.config;
        // As the trainer renders a checkpoint (Trainer::render).
        let sh_degree = state.sh_degree;
        let layer = match state.layer {
            checkpoint::RenderLayer::Scattering => None,
            checkpoint::RenderLayer::Env { set, env, fresnel } => {
                let n = set.len().max(1);
                Some(Layer::Env {
                    set: Gaussians::upload(ctx, &set)?,
                    env: EnvMap::upload(ctx, &env)?,
                    shading: ReflectionShading::new(ctx)?,
                    raster: Rasterizer::new(ctx, fresnel.channels(), Features::Plain)?,
                    // The colour kernel writes every Gaussian's features before the rasterizer reads them.
                    feat: Buffer::uninit(ctx, "embed.refl_features", fresnel.channels() as usize * n)?,
                    fresnel,
                })
            }
            checkpoint::RenderLayer::LightField { set, shape, params, shade } => {
                let n = set.len().max(1);
                Some(Layer::Light {
                    set: Gaussians::upload(ctx, &set)?,
                    params: Buffer::from_slice(ctx, "embed.mlp_params", &params)?,
                    shape,
                    shade,
                    shading: LightFieldShading::new(ctx)?,
                    mlp: Mlp::new(ctx)?,
                    raster: Rasterizer::new(ctx, tgs_pipelines::lightfield::CHANNELS, Features::Plain)?,
                    // The material kernel writes every Gaussian's features first.
                    feat: Buffer::uninit(ctx, "embed.lf_features", tgs_pipelines::lightfield::CHANNELS as usize * n)?,
                })
            }
        };
        Ok(SceneRenderer {
            ctx: ctx.clone(),
            scat: Gaussians::upload(ctx, &state.scattering)?,
            sh_degree,
            background: cfg.background_rgb()?,
            raster: Rasterizer::new(ctx, 3, Features::Sh { degree: cfg.sh_degree })?,
            stage: state.stage,
            last_samples: None,
            layer,
            views: HashMap::new(),
        })
    }

    /// Gaussians in the scattering set and in the reflection set (0 before Stage II).
    pub fn counts(&self) -> (u32, u32) {
        let refl = match &self.layer {
            None => 0,
            Some(Layer::Env { set, .. } | Layer::Light { set, .. }) => set.n,
        };
        (self.scat.n, refl)
    }

    /// Floats [`SceneRenderer::record`] writes for a `width` x `height` view.
    pub fn output_len(width: u32, height: u32) -> usize {
        3 * width as usize * height as usize
    }

    fn view(&mut self, w: u32, h: u32) -> Result<&mut View> {
        if !self.views.contains_key(&(w, h)) {
            let scat = frame_for(&self.raster, self.scat.n, w, h)?;
            let planes = (Plane::count(3) * w * h) as usize;
            let (refl, samples) = match &self.layer {
                None => (None, None),
                Some(Layer::Env { set, raster, .. }) => (Some(frame_for(raster, set.n, w, h)?), None),
                Some(Layer::Light { set, raster, shading, mlp, shape, .. }) => {
                    let cap = (w * h).min(mlp.max_capacity(shape));
                    (Some(frame_for(raster, set.n, w, h)?), Some((shading.sample_scratch(w, h)?, mlp.scratch(*shape, cap)?)))
                }
            };
            // The composite kernel writes every plane of every pixel.
            let composite = if self.layer.is_some() { Some(Buffer::uninit(&self.ctx, "embed.composite", planes)?) } else { None };
            self.views.insert((w, h), View { scat, refl, samples, composite });
        }
        Ok(self.views.get_mut(&(w, h)).expect("view buffers"))
    }

    /// Record the render of `cam` into `rec`, its colour copied to `out`
    /// (at least [`SceneRenderer::output_len`] f32). Keep `rec` (and this
    /// renderer) alive until the submission completes, then call
    /// [`SceneRenderer::complete`].
    pub fn record(&mut self, rec: &mut Recorder, cam: &Camera, out: &BufferBinding) -> Result<()> {
        cam.validate()?;
        let need = 4 * Self::output_len(cam.width, cam.height) as u64;
        if out.range < need {
            bail!("the output binding holds {} bytes; a {}x{} view needs {need}", out.range, cam.width, cam.height);
        }
        let (sh, bg) = (self.sh_degree, self.background);
        self.view(cam.width, cam.height)?;
        let v = &self.views[&(cam.width, cam.height)];
        self.raster.record_forward(rec, &self.scat, cam, &bg, sh, &v.scat)?;
        let colour = match (&self.layer, v.refl.as_ref(), v.composite.as_ref()) {
            (None, _, _) => &v.scat.out,
            (Some(Layer::Env { set, env, fresnel, shading, raster, feat }), Some(frame), Some(comp)) => {
                shading.record_color(rec, &tgs_pipelines::ColorInputs { g: set, env, cam, fresnel: *fresnel }, feat)?;
                raster.record_forward_with(rec, Splats::coloured(set, feat), cam, &vec![0.0; fresnel.channels() as usize], frame)?;
                shading.record_composite(rec, cam, *fresnel, &tgs_pipelines::reflection::CompositeInputs { scat: &v.scat.out, refl: &frame.out }, comp)?;
                comp
            }
            (Some(Layer::Light { set, params, shade, shading, mlp, raster, feat, .. }), Some(frame), Some(comp)) => {
                let (samples, scratch) = v.samples.as_ref().context("light-field sample buffers")?;
                shading.record_material(rec, &set.features, set.n, feat)?;
                raster.record_forward_with(rec, Splats::coloured(set, feat), cam, &[0.0; tgs_pipelines::lightfield::CHANNELS as usize], frame)?;
                shading.record_samples(rec, cam, shade, &frame.out, samples, &scratch.samples)?;
                mlp.record_forward_counted(rec, params, &samples.count, scratch)?;
                shading.record_composite(rec, cam, shade, &tgs_pipelines::lightfield::CompositeInputs { scat: &v.scat.out, refl: &frame.out, samples, phi: &scratch.out }, comp)?;
                comp
            }
            _ => bail!("view buffers missing for the reflection layer"),
        };
        rec.copy(&colour.binding(), out, need)?;
        Ok(())
    }

    /// After the submission of a [`SceneRenderer::record`] of `cam`
    /// completed: `true` when the frame was whole; `false` when a buffer
    /// was too small (it has been grown): record the view again.
    pub fn complete(&mut self, cam: &Camera) -> Result<bool> {
        let v = self.views.get_mut(&(cam.width, cam.height)).context("this view size was never recorded")?;
        let mut whole = self.raster.fit(&mut v.scat)?;
        match (&self.layer, v.refl.as_mut()) {
            (Some(Layer::Env { raster, .. }), Some(f)) => whole &= raster.fit(f)?,
            (Some(Layer::Light { raster, shade, .. }), Some(f)) => {
                whole &= raster.fit(f)?;
                if let Some((samples, scratch)) = v.samples.as_ref() {
                    let count = samples.count.download()?[0];
                    self.last_samples = Some(count);
                    if whole && count > scratch.capacity() {
                        bail!(
                            "{count} pixels of this {}x{} view reflect (R > {}); the light field evaluates at most {} on this device, so {} pixels show the scattering colour alone",
                            cam.width,
                            cam.height,
                            shade.threshold,
                            scratch.capacity(),
                            count - scratch.capacity()
                        );
                    }
                }
            }
            _ => {}
        }
        Ok(whole)
    }

    /// Render `cam` on this context's own queue (recording, submitting and
    /// re-recording until the frame is whole); the colour planes.
    pub fn render(&mut self, cam: &Camera) -> Result<Vec<f32>> {
        let out = Buffer::<f32>::uninit(&self.ctx, "embed.out", Self::output_len(cam.width, cam.height))?;
        loop {
            let mut rec = Recorder::new(&self.ctx)?;
            self.record(&mut rec, cam, &out.binding())?;
            rec.submit_and_wait()?;
            if self.complete(cam)? {
                return out.download();
            }
        }
    }
}

/// The test cameras of `run`'s dataset (its training cameras when it has no
/// test views), with the views' names, at the run's resolution.
pub fn run_cameras(run: &Path) -> Result<Vec<(String, Camera)>> {
    let (h, _) = checkpoint::read(&run.join(crate::train::run::CHECKPOINT))?;
    let data = crate::train::run::load_dataset(Path::new(&h.dataset), &h.config).with_context(|| format!("loading the run's dataset {}", h.dataset))?;
    let views = if data.test.is_empty() { &data.train } else { &data.test };
    Ok(views.iter().map(|v| (v.name.clone(), v.camera)).collect())
}
