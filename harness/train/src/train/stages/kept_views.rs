//! Training views' blend weights kept for a set whose geometry no longer
//! trains (Stage III: the reflection set's, with its geometry planes, and
//! the scattering set's while only its colour trains), within a memory
//! budget (`light_field.kept_binning_mib`, per set): each view is rendered
//! in full once, and its later renders and colour gradients sum the kept
//! weights instead (`pipelines/src/raster/kept_weights.rs`: the same
//! colour, the colour gradient up to the order of its sums). Views beyond
//! the budget are rendered in full every time, as without it.

use std::collections::HashMap;
use tgs_pipelines::KeptWeights;

#[derive(Default)]
pub struct KeptViews {
    views: HashMap<u32, KeptWeights>,
    /// Keeping stopped (the device could not hold another view's): the
    /// views not kept by then are rendered in full every time, as without
    /// a budget, rather than the run failing for memory it did not need.
    stopped: bool,
}

/// Which training view a forward renders, and the budget its set's kept
/// weights may take (MiB; 0 keeps none).
#[derive(Clone, Copy, Debug)]
pub struct KeepAs {
    pub view: u32,
    pub budget_mib: u32,
}

impl KeptViews {
    pub fn get(&self, view: u32) -> Option<&KeptWeights> {
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
    pub fn keep(&mut self, at: KeepAs, make: impl FnOnce(u64) -> anyhow::Result<Option<KeptWeights>>) {
        let KeepAs { view, budget_mib } = at;
        if self.stopped || budget_mib == 0 || self.views.contains_key(&view) {
            return;
        }
        let held: u64 = self.views.values().map(KeptWeights::bytes).sum();
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
                eprintln!("note: keeping training views' blend weights stopped after {} views ({e:#}); the others are rendered in full every time", self.views.len());
                self.stopped = true;
            }
        }
    }
}
