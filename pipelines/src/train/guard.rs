//! The divergence guard: one flag per checked array, set on the GPU to the
//! round's stamp when any value is NaN, infinite or beyond the array's
//! limit (`glsl/guard/finite.comp`), read back with the submission that
//! checks. A new stamp per round replaces a clearing pass: on lavapipe
//! every extra command in a step's submission costs a synchronisation.

use super::TrainableSet;
use super::{dispatch_items, kernel};
use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Kernel, Readback, Recorder};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    n: u32,
    slot: u32,
    limit: f32,
    stamp: u32,
}

pub struct Guard {
    ctx: Arc<Context>,
    kernel: Kernel,
    flags: Buffer<u32>,
    readback: Readback<u32>,
    /// Values per dispatch, forced ([`Guard::window`]).
    window: Option<usize>,
    /// The current round's stamp (never 0, the flags' initial value).
    stamp: std::cell::Cell<u32>,
}

impl Guard {
    /// A guard with `slots` flags (one per array checked in a recording).
    pub fn new(ctx: &Arc<Context>, slots: usize) -> Result<Guard> {
        if slots == 0 {
            bail!("a guard needs at least one slot");
        }
        Ok(Guard {
            ctx: ctx.clone(),
            kernel: kernel(ctx, "guard.finite", shaders::GUARD_FINITE, std::mem::size_of::<Push>() as u32)?,
            flags: Buffer::new(ctx, "guard.flags", slots)?,
            readback: Readback::new(ctx, "guard.readback", slots)?,
            window: None,
            stamp: std::cell::Cell::new(1),
        })
    }

    /// This guard with every array checked a window of about `elements`
    /// at a time even when it fits one binding (tests compare the two).
    pub fn window(mut self, elements: usize) -> Guard {
        self.window = Some(elements);
        self
    }

    pub fn slots(&self) -> usize {
        self.flags.len()
    }

    /// Start a round of checks: flags set by earlier rounds no longer
    /// count (nothing is recorded).
    pub fn next_round(&self) {
        let s = self.stamp.get().wrapping_add(1);
        self.stamp.set(if s == 0 { 1 } else { s });
    }

    /// Check the first `n` values of `data` into flag `slot`: set when one
    /// is NaN, infinite or of magnitude above `limit`.
    pub fn record_check(&self, rec: &mut Recorder, data: &Buffer<f32>, n: usize, limit: f32, slot: usize) -> Result<()> {
        if slot >= self.slots() {
            bail!("guard slot {slot} of {}", self.slots());
        }
        let n = n.min(data.len());
        // Arrays past one storage binding (SH 3 features of a million
        // Gaussians on lavapipe) are checked a window at a time.
        let fit = (self.ctx.caps().max_storage_buffer_range / 4) as usize;
        let per = crate::slice_units(n <= fit, fit as u64, self.window.map(|w| w as u64)).map_or(n, |u| u as usize);
        let mut start = 0;
        while start < n {
            let len = per.min(n - start);
            let p = Push { n: len as u32, slot: slot as u32, limit, stamp: self.stamp.get() };
            dispatch_items(rec, &self.kernel, &[data.slice(start, len), self.flags.binding()], bytemuck::bytes_of(&p), p.n, None)?;
            start += len;
        }
        Ok(())
    }

    /// Copy the flags for [`Guard::read`] (record after the checks).
    pub fn record_read(&self, rec: &mut Recorder) -> Result<()> {
        rec.read_back(&self.flags, 0, &self.readback)
    }

    /// The slots whose flag this round set, once the recording has completed.
    pub fn tripped(&self) -> Result<Vec<usize>> {
        let stamp = self.stamp.get();
        Ok(self.readback.read()?.iter().enumerate().filter(|(_, &f)| f == stamp).map(|(i, _)| i).collect())
    }
}

/// The guard over one Gaussian set's positions: every value finite and
/// within `means_limit` of the origin. Recorded into the submission that
/// steps the set: one dispatch and one copy. Positions are what runs away
/// without the loss showing it (a Gaussian far outside the scene is
/// culled); the other parameters cannot overflow under the learning rates
/// allowed (Adam zeroes non-finite gradients and moves a value by about
/// its rate, at most 1e3, an iteration), and a non-finite value among them
/// makes the loss of any view that sees it non-finite, which the driver
/// checks. Checking the other arrays too (and clearing the flags) cost
/// 9% of a Stage I iteration on lavapipe (perf/RESULTS.md, fifty-fifth).
pub struct SetGuard {
    guard: Guard,
    pub means_limit: f32,
}

impl SetGuard {
    pub fn new(ctx: &Arc<Context>, means_limit: f32) -> Result<SetGuard> {
        Ok(SetGuard { guard: Guard::new(ctx, 1)?, means_limit })
    }

    /// Check `set`'s positions and copy the flag for [`SetGuard::tripped`].
    pub fn record(&self, rec: &mut Recorder, set: &TrainableSet) -> Result<()> {
        self.guard.next_round();
        let means = &set.params.means;
        self.guard.record_check(rec, means, means.len(), self.means_limit, 0)?;
        self.guard.record_read(rec)
    }

    /// Whether the last completed recording found a bad position.
    pub fn tripped(&self) -> Result<bool> {
        Ok(!self.guard.tripped()?.is_empty())
    }
}
