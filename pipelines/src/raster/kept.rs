//! A view's binning kept for later forwards of the same geometry (Stage
//! III, whose scattering and reflection geometry are frozen): the depth
//! order, each Gaussian's intersection offset, the tile-sorted
//! intersections and each tile's range, copied aside once after a forward
//! that fitted its frame. A later forward of that view projects again (the
//! colours change) and copies the binning back instead of sorting. The
//! binning is a function of the geometry and the camera alone, so the
//! outputs and the backward's gradients are bit-identical to a full
//! forward's (tests/tests/kept_binning.rs).

use super::{Camera, Frame, Rasterizer, Splats};
use anyhow::{bail, Context as _, Result};
use tgs_engine::{Buffer, Recorder};

/// One view's binning, kept (see the module's note).
pub struct KeptBinning {
    n: u32,
    count: u32,
    tiles: u32,
    size: (u32, u32),
    data: Buffer<u32>,
}

impl KeptBinning {
    /// Bytes of device memory held.
    pub fn bytes(&self) -> u64 {
        self.data.bytes()
    }
    /// Intersections kept.
    pub fn intersections(&self) -> u32 {
        self.count
    }
}

/// The frame's binning arrays that the tile forward, the backward and
/// [`Rasterizer::fit`] read, with the length each keeps: the counters `fit`
/// and the gate read (the intersection total, no overflow), the depth
/// order, each rank's first intersection, the intersections' values and
/// Gaussians in tile order, the tile ranges. (The sort keys, the count and
/// the indirect arguments serve the binning alone.)
fn sections(frame: &Frame, n: u32, count: u32) -> [(&Buffer<u32>, usize); 6] {
    let (n, count) = (n as usize, count as usize);
    [
        (&frame.stats, 2),
        (&frame.depth_ids, n),
        (&frame.offsets, n + 1),
        (&frame.isect_vals, count),
        (&frame.isect_gid, count),
        (&frame.ranges, 2 * frame.tiles() as usize),
    ]
}

impl Rasterizer {
    /// Bytes [`Rasterizer::keep_binning`] would take for `frame`'s last
    /// view of `n` Gaussians (to check a budget before allocating).
    pub fn kept_binning_bytes(frame: &Frame, n: u32) -> u64 {
        4 * sections(frame, n, frame.last_intersections).iter().map(|s| s.1 as u64).sum::<u64>()
    }

    /// Keep the binning of `frame`'s last view of `n` Gaussians: call it
    /// after [`Rasterizer::fit`] returned true for that forward and before
    /// anything else used the frame (one submission of copies).
    pub fn keep_binning(&self, frame: &Frame, n: u32) -> Result<KeptBinning> {
        let count = frame.last_intersections;
        if count > frame.capacity {
            bail!("the frame's last view ({count} intersections) did not fit its capacity of {}: there is no binning to keep", frame.capacity);
        }
        let parts = sections(frame, n, count);
        let len: usize = parts.iter().map(|s| s.1).sum();
        let data = Buffer::<u32>::uninit(&self.ctx, "raster.kept_binning", len).context("keeping a view's binning")?;
        let mut rec = Recorder::new(&self.ctx)?;
        let mut at = 0;
        for (b, l) in parts {
            rec.copy(&b.slice(0, l), &data.slice(at, l), 4 * l as u64)?;
            at += l;
        }
        rec.submit_and_wait()?;
        Ok(KeptBinning { n, count, tiles: frame.tiles(), size: (frame.width, frame.height), data })
    }

    /// Record the forward of one view whose binning `kept` holds (the same
    /// Gaussians' geometry, the same camera; the features may differ): the
    /// projection, the binning copied back, the tile forward. The view fits
    /// its frame ([`Rasterizer::fit`] returns true after it).
    pub fn record_forward_kept(&self, rec: &mut Recorder, s: Splats, cam: &Camera, background: &[f32], frame: &Frame, kept: &KeptBinning) -> Result<()> {
        if kept.n != s.g.n {
            bail!("the kept binning is of {} Gaussians; the set has {}", kept.n, s.g.n);
        }
        if kept.size != (frame.width, frame.height) || kept.tiles != frame.tiles() {
            bail!("the kept binning is of a {}x{} view; the frame is {}x{}", kept.size.0, kept.size.1, frame.width, frame.height);
        }
        if kept.count > frame.capacity {
            bail!("the kept binning holds {} intersections; the frame takes {}", kept.count, frame.capacity);
        }
        let push = self.begin_forward(rec, &s, cam, background, frame)?;
        self.record_project(rec, s.g, s.features, &push, frame)?;
        let sc = rec.begin_scope("raster.kept_binning");
        let mut at = 0;
        for (b, l) in sections(frame, kept.n, kept.count) {
            rec.copy(&kept.data.slice(at, l), &b.slice(0, l), 4 * l as u64)?;
            at += l;
        }
        rec.end_scope(sc);
        self.record_tiles_forward(rec, &push, frame)
    }
}
