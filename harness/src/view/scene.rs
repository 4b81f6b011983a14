//! What the viewer shows: a run's checkpoints (Stage I, II, III), the
//! dataset's cameras, and the layers `tgs render` writes. The final image
//! is recorded on the GPU through [`SceneRenderer`] into the frame's
//! command buffer; the other layers come from the trainer's render, as
//! `tgs render` makes them, so both show the same pixels it writes.

use crate::data::image_io::ImageF;
use crate::data::Dataset;
use crate::embed::SceneRenderer;
use crate::eval::{expected_depth, layer_images, world_normals};
use crate::train::checkpoint;
use crate::train::live::Snapshot;
use crate::train::rundir::{stage_checkpoint, CHECKPOINT};
use crate::train::stage::Stage;
use crate::train::Trainer;
use anyhow::{bail, ensure, Context as _, Result};
use glam::DVec3;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::{pack_pixel, Camera, Pack, PixelOrder};

/// The layers in the order L steps through them; "final" is the GPU
/// composite, "gt" the dataset's photo, the rest `tgs render`'s PNG
/// suffixes (those a stage lacks are skipped).
pub const LAYERS: [&str; 11] = ["final", "gt", "normal", "depth", "scat", "refl", "R", "F0", "phi_mask", "normal_scat", "normal_refl"];

pub struct Scene {
    ctx: Arc<Context>,
    /// (label, file) of each checkpoint the run has, Stage I first.
    pub checkpoints: Vec<(String, PathBuf)>,
    pub checkpoint: usize,
    renderer: SceneRenderer,
    /// The trainer of the current checkpoint, for the layers (made when one is first shown).
    trainer: Option<Trainer>,
    pub data: Dataset,
    /// Test cameras (false) or training cameras (true).
    pub train_set: bool,
    pub camera: usize,
    pub layer: usize,
    pack: Pack,
    /// The final image's colour planes at the current size.
    colour: Option<Buffer<f32>>,
    /// The point the training cameras look at, and their mean up.
    pub target: DVec3,
    pub up: DVec3,
    /// Gaussians of the scattering and the reflection set.
    pub counts: (usize, usize),
    /// The layers the current checkpoint's render has, once one was made.
    known: Option<Vec<&'static str>>,
    /// A run still training (`tgs train --view`): its latest model, and
    /// the schedule entry, iteration and last iteration it is at.
    live: Option<LiveModel>,
}

/// The latest model of a run still training, and where in its schedule it is.
struct LiveModel {
    checkpoint: Arc<(checkpoint::Header, Vec<Vec<f32>>)>,
    label: String,
    iteration: u32,
    total: u32,
}

impl LiveModel {
    fn of(snap: Snapshot) -> LiveModel {
        LiveModel { iteration: snap.header.iteration, checkpoint: Arc::new((snap.header, snap.arrays)), label: snap.label, total: snap.total }
    }
}

impl Scene {
    pub fn open(ctx: &Arc<Context>, run: &Path) -> Result<Scene> {
        let last = run.join(CHECKPOINT);
        if !last.is_file() {
            bail!("{}: no checkpoint.bin: not a tgs run directory (or a run that has not saved yet)", run.display());
        }
        let mut checkpoints: Vec<(String, PathBuf)> =
            Stage::all().into_iter().map(|s| (s.name().to_string(), run.join(stage_checkpoint(s.number())))).filter(|(_, p)| p.is_file()).collect();
        let (h, _) = checkpoint::read(&last)?;
        let data = crate::train::run::load_dataset(Path::new(&h.dataset), &h.config).with_context(|| format!("loading the run's dataset {}", h.dataset))?;
        if data.train.is_empty() {
            bail!("{}: the run's dataset has no training cameras", data.root.display());
        }
        let renderer = SceneRenderer::load(ctx, &last)?;
        checkpoints.retain(|(l, _)| l != renderer.stage);
        checkpoints.push((renderer.stage.to_string(), last));
        Self::with(ctx, checkpoints, renderer, data, None)
    }

    /// The model of a run while it trains (the first snapshot).
    pub fn live(ctx: &Arc<Context>, snap: Snapshot) -> Result<Scene> {
        let h = &snap.header;
        let data = crate::train::run::load_dataset(Path::new(&h.dataset), &h.config).with_context(|| format!("loading the run's dataset {}", h.dataset))?;
        let renderer = SceneRenderer::from_checkpoint(ctx, h, snap.arrays.clone())?;
        let checkpoints = vec![(renderer.stage.to_string(), PathBuf::new())];
        Self::with(ctx, checkpoints, renderer, data, Some(LiveModel::of(snap)))
    }

    fn with(ctx: &Arc<Context>, checkpoints: Vec<(String, PathBuf)>, renderer: SceneRenderer, data: Dataset, live: Option<LiveModel>) -> Result<Scene> {
        let train: Vec<Camera> = data.train.iter().map(|v| v.camera).collect();
        let (target, up) = crate::render::look_target(&train);
        let (a, b) = renderer.counts();
        let train_set = data.test.is_empty();
        Ok(Scene {
            ctx: ctx.clone(),
            checkpoint: checkpoints.len() - 1,
            checkpoints,
            renderer,
            trainer: None,
            data,
            train_set,
            camera: 0,
            layer: 0,
            pack: Pack::new(ctx)?,
            colour: None,
            target,
            up,
            counts: (a as usize, b as usize),
            known: None,
            live,
        })
    }

    /// A newer snapshot of the training run.
    pub fn update(&mut self, snap: Snapshot) -> Result<()> {
        self.renderer = SceneRenderer::from_checkpoint(&self.ctx, &snap.header, snap.arrays.clone())?;
        let (a, b) = self.renderer.counts();
        self.counts = (a as usize, b as usize);
        if self.checkpoints[0].0 != self.renderer.stage {
            self.checkpoints[0].0 = self.renderer.stage.to_string();
            self.known = None;
        }
        self.trainer = None;
        self.live = Some(LiveModel::of(snap));
        Ok(())
    }

    /// While the run trains: the schedule entry, its iteration and the last.
    pub fn training(&self) -> Option<(&str, u32, u32)> {
        self.live.as_ref().map(|l| (l.label.as_str(), l.iteration, l.total))
    }

    /// The current checkpoint's stage ("I", "II" or "III").
    pub fn stage(&self) -> &str {
        &self.checkpoints[self.checkpoint].0
    }

    /// Load the next checkpoint (the layer stays if the stage has it).
    pub fn next_checkpoint(&mut self) -> Result<()> {
        if self.live.is_some() {
            // A run still training has one model: the latest.
            return Ok(());
        }
        let next = (self.checkpoint + 1) % self.checkpoints.len();
        let path = &self.checkpoints[next].1;
        self.renderer = SceneRenderer::load(&self.ctx, path)?;
        let (a, b) = self.renderer.counts();
        self.counts = (a as usize, b as usize);
        self.trainer = None;
        self.known = None;
        self.checkpoint = next;
        Ok(())
    }

    pub fn cameras(&self) -> &[crate::data::View] {
        if self.train_set {
            &self.data.train
        } else {
            &self.data.test
        }
    }

    /// The current dataset camera and its view's name.
    pub fn dataset_camera(&self) -> (&str, Camera) {
        let v = &self.cameras()[self.camera];
        (&v.name, v.camera)
    }

    pub fn step_camera(&mut self, by: i64) {
        let n = self.cameras().len() as i64;
        self.camera = (self.camera as i64 + by).rem_euclid(n) as usize;
    }

    pub fn switch_set(&mut self) {
        if !self.data.test.is_empty() {
            self.train_set = !self.train_set;
            self.camera = 0;
        }
    }

    pub fn layer_name(&self) -> &'static str {
        LAYERS[self.layer]
    }

    /// Step to the next (or previous) layer this stage has.
    /// Show the layer called `name` (one of [`LAYERS`]).
    pub fn show_layer(&mut self, name: &str) {
        if let Some(i) = LAYERS.iter().position(|&l| l == name) {
            self.layer = i;
        }
    }

    pub fn step_layer(&mut self, by: i64) {
        let later = self.stage() != Stage::SCATTERING.name();
        let has = |name: &str| match (name, &self.known) {
            ("final" | "gt", _) => true,
            (_, Some(k)) => k.contains(&name),
            ("normal" | "depth", None) => true,
            // Before the stage has rendered once, a guess: a later stage's
            // layers (one it lacks is stepped over when drawn: host_layer).
            (_, None) => later,
        };
        let n = LAYERS.len() as i64;
        let mut l = self.layer as i64;
        for _ in 0..n {
            l = (l + by).rem_euclid(n);
            if has(LAYERS[l as usize]) {
                break;
            }
        }
        self.layer = l as usize;
    }

    /// Record the final image of `cam` packed into `pixels`; false when the
    /// layer is not the final image (then [`Scene::host_layer`] fills them).
    pub fn record_final(&mut self, rec: &mut Recorder, cam: &Camera, order: PixelOrder, pixels: &Buffer<u32>) -> Result<bool> {
        self.record_final_scaled(rec, cam, (cam.width, cam.height, 1), order, pixels)
    }

    /// As [`Scene::record_final`] for a `shown` = (width, height, scale)
    /// image drawn from `cam`, a frame `scale` times smaller on each side
    /// (a moving camera's): each of its pixels fills scale x scale of them.
    pub fn record_final_scaled(&mut self, rec: &mut Recorder, cam: &Camera, shown: (u32, u32, u32), order: PixelOrder, pixels: &Buffer<u32>) -> Result<bool> {
        if self.layer != 0 {
            return Ok(false);
        }
        let (w, h, scale) = shown;
        ensure!(
            (w.div_ceil(scale), h.div_ceil(scale)) == (cam.width, cam.height),
            "a {w}x{h} image at 1/{scale} needs a {}x{} camera, not {}x{}",
            w.div_ceil(scale),
            h.div_ceil(scale),
            cam.width,
            cam.height
        );
        let n = SceneRenderer::output_len(cam.width, cam.height);
        if self.colour.as_ref().is_none_or(|c| c.len() < n) {
            // The renderer's copy writes every float before the pack reads them.
            self.colour = Some(Buffer::uninit(&self.ctx, "view.colour", n)?);
        }
        let colour = self.colour.as_ref().expect("made above").slice(0, n);
        self.renderer.record(rec, cam, &colour)?;
        self.pack.record_scaled(rec, &colour, (w, h), scale, order, &pixels.binding())?;
        Ok(true)
    }

    /// Pixels the light field ran on in the last final image (Stage III).
    pub fn phi_pixels(&self) -> Option<u32> {
        self.renderer.last_samples
    }

    /// After the frame's submission: whether the final image was whole
    /// (else the renderer grew its buffers: draw again).
    pub fn complete(&mut self, cam: &Camera) -> Result<bool> {
        if self.layer != 0 {
            return Ok(true);
        }
        self.renderer.complete(cam)
    }

    /// The current layer of `cam` (not the final image) as packed pixels;
    /// `at` is the dataset camera it stands at, for the photo.
    pub fn host_layer(&mut self, cam: &Camera, at: Option<&Camera>, order: PixelOrder) -> Result<Vec<u32>> {
        let name = self.layer_name();
        let img = if name == "gt" {
            let v = &self.cameras()[self.camera];
            match at {
                Some(c) if (c.width, c.height) == (cam.width, cam.height) => v.image.clone(),
                _ => resample(&v.image, cam.width, cam.height),
            }
        } else {
            if self.trainer.is_none() {
                let path = &self.checkpoints[self.checkpoint].1;
                let (h, arrays) = match &self.live {
                    Some(l) => (l.checkpoint.0.clone(), l.checkpoint.1.clone()),
                    None => checkpoint::read(path)?,
                };
                self.trainer = Some(checkpoint::restore(&self.ctx, path, (h, arrays), &self.data)?);
            }
            let tr = self.trainer.as_mut().expect("made above");
            let r = tr.render(cam)?;
            let depth = expected_depth(&r);
            let mut layers = layer_images(&r, &world_normals(&r, cam), &depth, cam);
            self.known = Some(layers.iter().map(|(s, _)| if s.is_empty() { "final" } else { *s }).collect());
            let mut take = |name: &str| layers.iter().position(|(s, _)| *s == name).map(|i| layers.swap_remove(i).1);
            match take(name) {
                Some(img) => img,
                None => {
                    // A layer guessed before the stage rendered that it lacks: the next it has.
                    self.step_layer(1);
                    let next = self.layer_name();
                    take(next).with_context(|| format!("Stage {} renders no '{name}' layer", self.stage()))?
                }
            }
        };
        Ok(pack_image(&img, order))
    }
}

/// An image (1 or 3 channels, interleaved) as packed 8-bit pixels.
pub fn pack_image(img: &ImageF, order: PixelOrder) -> Vec<u32> {
    let c = img.channels as usize;
    img.data
        .chunks(c)
        .map(|p| {
            let rgb = if c >= 3 { [p[0], p[1], p[2]] } else { [p[0]; 3] };
            pack_pixel(rgb, order)
        })
        .collect()
}

/// Nearest-neighbour resampling to `w` x `h` (the photo beside a moved camera).
fn resample(img: &ImageF, w: u32, h: u32) -> ImageF {
    let c = img.channels as usize;
    let mut data = Vec::with_capacity(w as usize * h as usize * c);
    for y in 0..h {
        let sy = ((y as f64 + 0.5) * img.height as f64 / h as f64) as usize;
        for x in 0..w {
            let sx = ((x as f64 + 0.5) * img.width as f64 / w as f64) as usize;
            let at = (sy.min(img.height as usize - 1) * img.width as usize + sx.min(img.width as usize - 1)) * c;
            data.extend_from_slice(&img.data[at..at + c]);
        }
    }
    ImageF { width: w, height: h, channels: img.channels, data }
}
