//! The divergence guard: one flag per checked array, set on the GPU when
//! any value is NaN, infinite or beyond the array's limit
//! (`glsl/guard/finite.comp`), read back with the submission that checks.
//! A training step's state is checked this way every iteration for a
//! pass over its parameters, with no read-back of the parameters.

use super::{dispatch_items, kernel};
use crate::shaders;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use super::TrainableSet;
use tgs_engine::{Buffer, Context, Kernel, Readback, Recorder};

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    n: u32,
    slot: u32,
    limit: f32,
}

pub struct Guard {
    ctx: Arc<Context>,
    kernel: Kernel,
    flags: Buffer<u32>,
    readback: Readback<u32>,
    /// Values per dispatch, forced ([`Guard::window`]).
    window: Option<usize>,
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

    /// Clear every flag (record before the checks).
    pub fn record_clear(&self, rec: &mut Recorder) -> Result<()> {
        rec.fill(&self.flags.binding(), 0)
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
            let p = Push { n: len as u32, slot: slot as u32, limit };
            dispatch_items(rec, &self.kernel, &[data.slice(start, len), self.flags.binding()], bytemuck::bytes_of(&p), p.n, None)?;
            start += len;
        }
        Ok(())
    }

    /// Copy the flags for [`Guard::read`] (record after the checks).
    pub fn record_read(&self, rec: &mut Recorder) -> Result<()> {
        rec.read_back(&self.flags, 0, &self.readback)
    }

    /// The slots whose flag is set, once the recording has completed.
    pub fn tripped(&self) -> Result<Vec<usize>> {
        Ok(self.readback.read()?.iter().enumerate().filter(|(_, &f)| f != 0).map(|(i, _)| i).collect())
    }
}

/// The arrays [`SetGuard`] checks, the first four of `Gaussians::buffers`.
pub const SET_ARRAYS: [&str; 4] = ["means", "log-scales", "rotations", "opacity"];

/// The guard over one Gaussian set's geometry and opacity (means, log-
/// scales, rotations, opacity): every value finite, the positions within
/// `means_limit` of the origin. Recorded into the submission that steps
/// the set, so it costs dispatches, not a submission of its own. The
/// features (48 of a Gaussian's 58 values at SH 3) are left out: checking
/// them every iteration cost as much as the rest several times over on
/// lavapipe, and a non-finite colour shows in the loss of any view that
/// sees it, which the driver checks.
pub struct SetGuard {
    guard: Guard,
    pub means_limit: f32,
}

impl SetGuard {
    pub fn new(ctx: &Arc<Context>, means_limit: f32) -> Result<SetGuard> {
        Ok(SetGuard { guard: Guard::new(ctx, SET_ARRAYS.len())?, means_limit })
    }

    /// Clear, check `set`'s parameter arrays and copy the flags for
    /// [`SetGuard::tripped`].
    pub fn record(&self, rec: &mut Recorder, set: &TrainableSet) -> Result<()> {
        self.guard.record_clear(rec)?;
        for (k, b) in set.params.buffers().iter().enumerate().take(SET_ARRAYS.len()) {
            self.guard.record_check(rec, b, b.len(), if k == 0 { self.means_limit } else { f32::MAX }, k)?;
        }
        self.guard.record_read(rec)
    }

    /// The arrays found bad by the last completed recording.
    pub fn tripped(&self) -> Result<Vec<&'static str>> {
        Ok(self.guard.tripped()?.into_iter().map(|i| SET_ARRAYS[i]).collect())
    }
}
