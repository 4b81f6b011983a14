//! Training views' binnings kept for a set whose geometry no longer
//! trains (Stage III: the scattering set when only its colour trains, and
//! the reflection set), within a memory budget
//! (`light_field.kept_binning_mib`, per set): each view is binned once, and
//! its later forwards copy the binning back instead of sorting again
//! (`pipelines/src/raster/kept.rs`; the same outputs, bit for bit). Views
//! beyond the budget are binned every time, as without it.

use std::collections::HashMap;
use tgs_pipelines::{Frame, KeptBinning, Rasterizer};

#[derive(Default)]
pub struct KeptViews {
    views: HashMap<u32, KeptBinning>,
    /// Keeping stopped (the device could not hold another binning): the
    /// views not kept by then are binned every time, as without a budget,
    /// rather than the run failing for memory it did not need.
    stopped: bool,
}

/// Which training view a forward renders, and the budget its set's kept
/// binnings may take (MiB; 0 keeps none).
#[derive(Clone, Copy, Debug)]
pub struct KeepAs {
    pub view: u32,
    pub budget_mib: u32,
}

impl KeptViews {
    pub fn get(&self, view: u32) -> Option<&KeptBinning> {
        self.views.get(&view)
    }
    /// Drop every kept binning (the geometry is about to change).
    pub fn clear(&mut self) {
        self.views.clear();
        self.stopped = false;
    }
    /// After a forward of training view `view` (`n` Gaussians) that fitted
    /// `frame`, with nothing recorded on the frame since: keep its binning
    /// if it is not kept yet and the budget has room. A device that cannot
    /// hold it stops the keeping (said once on stderr), not the run.
    pub fn keep(&mut self, raster: &Rasterizer, frame: &Frame, n: u32, at: KeepAs) {
        let KeepAs { view, budget_mib } = at;
        if self.stopped || self.views.contains_key(&view) {
            return;
        }
        let held: u64 = self.views.values().map(KeptBinning::bytes).sum();
        if held + Rasterizer::kept_binning_bytes(frame, n) > budget_mib as u64 * (1 << 20) {
            return;
        }
        match raster.keep_binning(frame, n) {
            Ok(k) => {
                self.views.insert(view, k);
            }
            Err(e) => {
                eprintln!("note: keeping training views' binnings stopped after {} views ({e:#}); the others are binned every time", self.views.len());
                self.stopped = true;
            }
        }
    }
}
