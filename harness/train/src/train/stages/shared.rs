//! What the trainer lends the stages after Stage I, and the trait it
//! drives them through.
//!
//! Stage I's scattering set is the base every later stage renders over, so
//! the trainer owns it; a later stage (Stage II's reflection set and cube
//! map, Stage III's light field) is one [`LaterStage`] the trainer holds
//! from the stage's start to the next, begun by the stage's own `begin`
//! (its `stage.rs`) and then stepped, rendered, written and handed on
//! through this trait without the trainer knowing which it is.

use super::reflection::decision::ReflDecision;
use super::rendered::ReflRendered;
use super::scattering::{ScatteringModel, StepOutput};
use super::views::Views;
use crate::train::config::TrainConfig;
use crate::train::stage::Stage;
use anyhow::Result;
use std::any::Any;
use std::path::Path;
use tgs_engine::Buffer;
use tgs_pipelines::{Camera, TrainableSet};

/// The frozen scattering colour of every training view (3 planes each),
/// rendered when Stage II begins and again after a resume, or after a
/// stage that changed the scattering set.
#[derive(Default)]
pub struct ScatCache {
    bufs: Vec<Buffer<f32>>,
    /// The SH degree the colours were rendered at.
    sh: u32,
}

impl ScatCache {
    pub fn is_empty(&self) -> bool {
        self.bufs.is_empty()
    }
    pub fn clear(&mut self) {
        self.bufs.clear();
    }
    /// The next view's colour, rendered at SH degree `sh` (every view's
    /// must be at the same degree).
    pub fn push(&mut self, buf: Buffer<f32>, sh: u32) {
        debug_assert!(self.bufs.is_empty() || self.sh == sh);
        self.sh = sh;
        self.bufs.push(buf);
    }
    pub fn get(&self, view: usize) -> Option<&Buffer<f32>> {
        self.bufs.get(view)
    }
    /// Every view's colour, rendered with `scattering` at SH degree `sh`
    /// unless all are there at that degree.
    pub fn ensure(&mut self, views: &Views, scattering: &mut ScatteringModel, sh: u32) -> Result<()> {
        if self.bufs.len() == views.cameras.len() && self.sh == sh {
            return Ok(());
        }
        self.bufs.clear();
        self.sh = sh;
        for cam in &views.cameras {
            let buf = Buffer::<f32>::new(&views.ctx, "train.scat_cache", 3 * (cam.width * cam.height) as usize)?;
            scattering.render_color_into(cam, sh, &views.background, &buf)?;
            self.bufs.push(buf);
        }
        Ok(())
    }
}

/// What a later stage may use for a transition or an iteration.
pub struct Shared<'a> {
    pub cfg: &'a TrainConfig,
    pub views: &'a Views,
    /// Stage I's set: rendered under the later stage, trained with it
    /// where its settings say so.
    pub scattering: &'a mut ScatteringModel,
    pub cache: &'a mut ScatCache,
}

/// One iteration as the trainer schedules it.
#[derive(Clone, Copy, Debug)]
pub struct Iteration {
    /// Over the whole run (1-based): the scattering set's Adam step count.
    pub global: u32,
    /// Within the stage (1-based): the stage's Adam step count.
    pub stage: u32,
    /// The training view.
    pub view: u32,
    /// Time every kernel.
    pub profile: bool,
}

/// A stage after Stage I, as the trainer drives it.
pub trait LaterStage: Any {
    /// Which stage this is.
    fn stage(&self) -> Stage;
    /// One iteration on view `x.view`.
    fn iterate(&mut self, s: Shared<'_>, x: &Iteration) -> Result<StepOutput>;
    /// `cam` rendered and composited over the scattering colour `scat`.
    fn render(&mut self, cam: &Camera, scat: &Buffer<f32>) -> Result<ReflRendered>;
    /// The reflection set.
    fn set(&self) -> &TrainableSet;
    /// The stage's outputs in the run directory `out` (at the end of a run
    /// that stops in this stage).
    fn write_outputs(&self, out: &Path) -> Result<()>;
    /// The reflection set (with its Adam moments), for the next stage.
    fn into_set(self: Box<Self>) -> TrainableSet;
    /// The stage's part of a checkpoint: its header (JSON, with the
    /// decision `d` and an `arrays` list) and its arrays' buffers and
    /// lengths appended to `bufs` in that list's order.
    fn save_state<'a>(&'a self, d: &ReflDecision, bufs: &mut Vec<(&'a Buffer<f32>, usize)>) -> Result<serde_json::Value>;
    /// The fraction of pixels the stage's light was evaluated at since the
    /// last call, where the stage measures it.
    fn take_coverage(&mut self) -> Option<f64> {
        None
    }
    /// For the trainer's typed views of the running stage
    /// (`Trainer::reflection`, `Trainer::light_field`).
    fn as_any(&self) -> &dyn Any;
    /// The same, to change: for a stage that sets up its own model when it begins again.
    fn as_any_mut(&mut self) -> Option<&mut dyn Any> {
        None
    }
}
