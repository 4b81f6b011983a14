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

use crate::train::checkpoint::{self, RenderLayer};
use crate::train::stages::layer::frame_for;
use anyhow::{bail, Context as _, Result};
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use tgs_engine::{Buffer, BufferBinding, Context, Recorder};
use tgs_pipelines::{Camera, Features, Frame, Gaussians, Plane, Rasterizer};

/// Per image size: the scattering set's frame, and the composite of a run
/// past Stage I (its reflection layer keeps its own buffers).
struct View {
    scat: Frame,
    composite: Option<Buffer<f32>>,
}

pub struct SceneRenderer {
    ctx: Arc<Context>,
    scat: Gaussians,
    sh_degree: u32,
    background: [f32; 3],
    raster: Rasterizer,
    /// The later stage's reflection layer (its stage's `render.rs`), after Stage I.
    layer: Option<Box<dyn RenderLayer>>,
    views: HashMap<(u32, u32), View>,
    /// The stage the run finished ("I", "II" or "III").
    pub stage: &'static str,
    /// Pixels the light field was evaluated on in the last completed view (Stage III).
    pub last_samples: Option<u32>,
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
        let state = checkpoint::render_state(h, arrays, ctx)?;
        let cfg = &h.config;
        // As the trainer renders a checkpoint (Trainer::render).
        let sh_degree = state.sh_degree;
        let layer = state.layer;
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
        (self.scat.n, self.layer.as_ref().map_or(0, |l| l.gaussians()))
    }

    /// Floats [`SceneRenderer::record`] writes for a `width` x `height` view.
    pub fn output_len(width: u32, height: u32) -> usize {
        3 * width as usize * height as usize
    }

    fn view(&mut self, w: u32, h: u32) -> Result<&mut View> {
        if !self.views.contains_key(&(w, h)) {
            let scat = frame_for(&self.raster, self.scat.n, w, h)?;
            let planes = (Plane::count(3) * w * h) as usize;
            // The composite kernel writes every plane of every pixel.
            let composite = if self.layer.is_some() { Some(Buffer::uninit(&self.ctx, "embed.composite", planes)?) } else { None };
            self.views.insert((w, h), View { scat, composite });
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
        let sc = rec.begin_scope("view.scattering");
        // The composite reads the scattering set's colour alone.
        self.raster.record_forward_colour(rec, &self.scat, cam, &bg, sh, &v.scat)?;
        rec.end_scope(sc);
        let colour = match (self.layer.as_mut(), v.composite.as_ref()) {
            (None, _) => &v.scat.out,
            (Some(layer), Some(comp)) => {
                let sc = rec.begin_scope("view.reflection");
                layer.record(rec, cam, &v.scat.out, comp)?;
                rec.end_scope(sc);
                comp
            }
            (Some(_), None) => bail!("view buffers missing for the reflection layer"),
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
        if let Some(layer) = self.layer.as_mut() {
            whole = layer.complete(cam, whole)?;
            self.last_samples = layer.last_samples();
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
