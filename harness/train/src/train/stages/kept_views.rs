//! Training views' binnings or blend weights kept for a set whose geometry
//! no longer trains (Stage III: the reflection set's binnings, and the
//! scattering set's blend weights while only its colour trains), within a
//! memory budget (`light_field.kept_binning_mib`, per set): each view is
//! binned (or rendered in full) once, and its later forwards copy the
//! binning back (`pipelines/src/raster/kept.rs`; the same outputs, bit for
//! bit) or sum the kept weights (`pipelines/src/raster/kept_weights.rs`;
//! the same colour, the colour gradient up to the order of its sums)
//! instead. Views beyond the budget are binned every time, as without it.

use std::collections::HashMap;
use tgs_pipelines::{KeptBinning, KeptWeights};

/// What a set keeps per view.
pub trait Kept {
    /// Device bytes held.
    fn bytes(&self) -> u64;
}

impl Kept for KeptBinning {
    fn bytes(&self) -> u64 {
        KeptBinning::bytes(self)
    }
}

impl Kept for KeptWeights {
    fn bytes(&self) -> u64 {
        KeptWeights::bytes(self)
    }
}

pub struct KeptViews<T> {
    views: HashMap<u32, T>,
    /// Keeping stopped (the device could not hold another view's): the
    /// views not kept by then are binned every time, as without a budget,
    /// rather than the run failing for memory it did not need.
    stopped: bool,
}

impl<T> Default for KeptViews<T> {
    fn default() -> Self {
        KeptViews { views: HashMap::new(), stopped: false }
    }
}

/// Which training view a forward renders, and the budget its set's kept
/// binnings may take (MiB; 0 keeps none).
#[derive(Clone, Copy, Debug)]
pub struct KeepAs {
    pub view: u32,
    pub budget_mib: u32,
}

impl<T: Kept> KeptViews<T> {
    pub fn get(&self, view: u32) -> Option<&T> {
        self.views.get(&view)
    }
    /// Drop everything kept (the geometry is about to change).
    pub fn clear(&mut self) {
        self.views.clear();
        self.stopped = false;
    }
    /// After a forward of training view `at.view` that fitted its frame,
    /// with nothing recorded on the frame since: keep what `make` returns
    /// for it, given the bytes the budget has left (`Ok(None)`: it does not
    /// fit), if the view is not kept yet and the budget has room. A device
    /// that cannot hold it stops the keeping (said once on stderr), not the
    /// run.
    pub fn keep(&mut self, at: KeepAs, make: impl FnOnce(u64) -> anyhow::Result<Option<T>>) {
        let KeepAs { view, budget_mib } = at;
        if self.stopped || budget_mib == 0 || self.views.contains_key(&view) {
            return;
        }
        let held: u64 = self.views.values().map(Kept::bytes).sum();
        let budget = budget_mib as u64 * (1 << 20);
        if held >= budget {
            return;
        }
        match make(budget - held) {
            Ok(Some(k)) => {
                self.views.insert(view, k);
            }
            Ok(None) => {}
            Err(e) => {
                eprintln!("note: keeping training views' binnings stopped after {} views ({e:#}); the others are binned every time", self.views.len());
                self.stopped = true;
            }
        }
    }
}

/// [`KeptViews::keep`]'s maker of a view's binning: `frame`'s last view of
/// `n` Gaussians, if its binning fits the bytes left.
pub fn binning<'a>(raster: &'a tgs_pipelines::Rasterizer, frame: &'a tgs_pipelines::Frame, n: u32) -> impl FnOnce(u64) -> anyhow::Result<Option<KeptBinning>> + 'a {
    move |left| {
        if tgs_pipelines::Rasterizer::kept_binning_bytes(frame, n) > left {
            return Ok(None);
        }
        raster.keep_binning(frame, n).map(Some)
    }
}
