//! Training views' blend weights kept for a set whose geometry no longer
//! trains (Stage III: the reflection set's, with its geometry planes, and
//! the scattering set's while only its colour trains), within a memory
//! budget (`light_field.kept_binning_mib`, per set): each view is rendered
//! in full once, and its later renders and colour gradients sum the kept
//! weights instead (`pipelines/src/raster/kept_weights.rs`: the same
//! colour, the colour gradient up to the order of its sums). Views beyond
//! the budget are rendered in full and their weights captured for that
//! visit (the last such view's held beyond the budget), so every step
//! takes its gradient from weights; a
//! view whose weights alone exceed the budget is never captured (its
//! steps walk the tiles, whatever the history).

use std::collections::{HashMap, HashSet};
use tgs_pipelines::KeptWeights;

#[derive(Default)]
pub struct KeptViews {
    views: HashMap<u32, KeptWeights>,
    /// The last captured view's weights that the budget had no room for,
    /// and that view: used for it until another view's replace them.
    beyond: Option<(u32, KeptWeights)>,
    /// Views whose weights alone exceed the budget (never captured).
    too_big: HashSet<u32>,
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
    /// The weights of `view`: kept, or the last ones captured beyond the
    /// budget where they are this view's.
    pub fn get(&self, view: u32) -> Option<&KeptWeights> {
        self.views.get(&view).or(self.beyond.as_ref().filter(|b| b.0 == view).map(|b| &b.1))
    }
    /// Drop everything kept (the geometry is about to change).
    pub fn clear(&mut self) {
        self.views.clear();
        self.beyond = None;
        self.too_big.clear();
        self.stopped = false;
    }
    /// Whether a full forward of `at.view` would capture its weights
    /// ([`Self::capture`]): [`Self::get`] has none for it, and it is not
    /// past capturing (budget 0, too big, or capturing stopped).
    pub fn would_capture(&self, at: KeepAs) -> bool {
        !self.stopped && at.budget_mib > 0 && self.get(at.view).is_none() && !self.too_big.contains(&at.view)
    }
    /// After a full forward of training view `at.view` that fitted its
    /// frame, with nothing recorded on the frame since, where
    /// [`Self::would_capture`]: its weights from `make` (given the whole
    /// budget in bytes; `Ok(None)` when they exceed it), kept if the budget
    /// has room, or else held beyond it in place of the last view's so
    /// held; either way [`Self::get`] then has them, so that every step of
    /// a frozen set takes its colour gradient from weights whatever the
    /// budget held before (a resumed run steps as the run it continues).
    /// None are captured for a view whose weights alone exceed the budget
    /// or a texel or record limit (remembered: never captured again), and
    /// after the device could not hold them once (said on stderr): its
    /// steps walk the tiles.
    pub fn capture(&mut self, at: KeepAs, make: impl FnOnce(u64) -> anyhow::Result<Option<KeptWeights>>) {
        let KeepAs { view, budget_mib } = at;
        if !self.would_capture(at) {
            return;
        }
        let budget = budget_mib as u64 * (1 << 20);
        let w = match make(budget) {
            Ok(Some(w)) => w,
            Ok(None) => {
                self.too_big.insert(view);
                return;
            }
            Err(e) => {
                eprintln!("note: capturing training views' blend weights stopped after {} views ({e:#}); the others are rendered and differentiated in full", self.views.len());
                self.stopped = true;
                return;
            }
        };
        let held: u64 = self.views.values().map(KeptWeights::bytes).sum();
        if held + w.bytes() > budget {
            self.beyond = Some((view, w));
        } else {
            self.views.insert(view, w);
        }
    }
}
