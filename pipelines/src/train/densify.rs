//! Adaptive density control on the GPU (method-notes §1.11): statistics per
//! view, then clone / split / prune decided per Gaussian, compacted with the
//! exclusive scan and written into fresh buffers. Only the new total (4
//! bytes) comes back to the host, to size the new buffers.

use super::set::TrainableSet;
use super::{dispatch_items, grid, kernel};
use crate::raster::{Frame, Gaussians};
use crate::scan::{Count, PrefixSum, ScanScratch};
use crate::shaders;
use anyhow::Result;
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, BufferBinding, Context, Kernel, Recorder};

/// Thresholds of one densification step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DensifyParams {
    /// Clone/split when the mean screen gradient reaches this (NDC units).
    pub grad_threshold: f32,
    /// Clone at or below this world scale, split above (percent_dense * extent).
    pub dense_scale: f32,
    /// Prune below this opacity.
    pub opacity_min: f32,
    /// Also prune large Gaussians (screen radius / world scale).
    pub prune_big: bool,
    pub big_screen: f32,
    pub big_world: f32,
    /// Clone and split (false: prune only).
    pub grow: bool,
    /// Seed of the split children's offsets.
    pub seed: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct MarkPush {
    n: u32,
    grow: u32,
    prune_big: u32,
    pad: u32,
    grad_threshold: f32,
    dense_scale: f32,
    opacity_min: f32,
    big_world: f32,
    big_screen: f32,
}

/// What one densification did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DensifyReport {
    pub before: u32,
    pub after: u32,
}

pub struct Densifier {
    ctx: Arc<Context>,
    scan: PrefixSum,
    stats: Kernel,
    mark: Kernel,
    apply: Kernel,
    reset: Kernel,
    /// Source Gaussians per copy dispatch, forced ([`Densifier::slice`]).
    slice: Option<u32>,
}

impl Densifier {
    pub fn new(ctx: &Arc<Context>) -> Result<Densifier> {
        Ok(Densifier {
            ctx: ctx.clone(),
            scan: PrefixSum::new(ctx)?,
            stats: kernel(ctx, "densify.stats", shaders::DENSIFY_STATS, 4)?,
            mark: kernel(ctx, "densify.mark", shaders::DENSIFY_MARK, std::mem::size_of::<MarkPush>() as u32)?,
            apply: kernel(ctx, "densify.apply", shaders::DENSIFY_APPLY, 24)?,
            reset: kernel(ctx, "densify.opacity_reset", shaders::DENSIFY_OPACITY_RESET, 8)?,
            slice: None,
        })
    }

    /// This densifier with every array copied in slices of `gaussians`
    /// source Gaussians (rounded down to a multiple of 64) even when it
    /// fits one binding: tests compare the sliced copy with the whole.
    pub fn slice(mut self, gaussians: u32) -> Densifier {
        self.slice = Some(gaussians);
        self
    }

    /// Source Gaussians per copy dispatch of an array of `width` floats a
    /// Gaussian: all `n` while the source and the `total` outputs each fit
    /// one storage binding and no slice is forced; else a multiple of 64
    /// whose outputs (at most two a source: a clone or a split) fit one
    /// binding past an aligned start.
    fn copy_slice(&self, n: u32, total: u32, width: u32) -> u32 {
        let caps = self.ctx.caps();
        let (max_f, align_f) = (caps.max_storage_buffer_range / 4, (caps.min_storage_buffer_offset_alignment / 4).max(1));
        let w = width.max(1) as u64;
        let fit = max_f.saturating_sub(align_f) / (2 * w);
        match crate::slice_units((n.max(total) as u64) * w <= max_f, fit, self.slice.map(u64::from)) {
            None => n,
            Some(per) => per.min(u32::MAX as u64) as u32,
        }
    }

    /// Record the statistics update from the last forward/backward on `frame`.
    pub fn record_stats(&self, rec: &mut Recorder, set: &TrainableSet, frame: &Frame) -> Result<()> {
        self.record_stats_on(rec, set, frame, None)
    }

    /// The grid of [`Densifier::record_stats`], for a gate.
    pub fn stats_grid(&self, set: &TrainableSet) -> [u32; 3] {
        grid(&self.ctx, set.len())
    }

    /// As [`Densifier::record_stats`], with the workgroup counts read from
    /// `args` (see `Rasterizer::record_fit_gate`).
    pub fn record_stats_gated(&self, rec: &mut Recorder, set: &TrainableSet, frame: &Frame, args: &BufferBinding) -> Result<()> {
        self.record_stats_on(rec, set, frame, Some(args))
    }

    fn record_stats_on(&self, rec: &mut Recorder, set: &TrainableSet, frame: &Frame, args: Option<&BufferBinding>) -> Result<()> {
        let n = set.len();
        if n == 0 {
            return Ok(());
        }
        let bindings = [frame.densify.binding(), frame.radii.binding(), set.accum.binding(), set.denom.binding(), set.max_radii.binding()];
        dispatch_items(rec, &self.stats, &bindings, bytemuck::bytes_of(&n), n, args)
    }

    /// Record the opacity reset: o <- min(o, cap), opacity moments zeroed.
    pub fn record_opacity_reset(&self, rec: &mut Recorder, set: &TrainableSet, cap: f32) -> Result<()> {
        let n = set.len();
        if n == 0 {
            return Ok(());
        }
        let raw = (cap / (1.0 - cap)).ln();
        let push: [u32; 2] = [n, raw.to_bits()];
        rec.dispatch(&self.reset, &[set.params.opacity.binding(), set.m.opacity.binding(), set.v.opacity.binding()], bytemuck::cast_slice(&push), grid(&self.ctx, n))
    }

    /// Clone, split and prune `set` (two submissions and a 4-byte read-back).
    /// The statistics of the result start at zero.
    pub fn densify(&self, set: &mut TrainableSet, p: &DensifyParams) -> Result<DensifyReport> {
        let ctx = &self.ctx;
        let n = set.len();
        let counts = Buffer::<u32>::new(ctx, "densify.counts", n as usize + 1)?;
        let action = Buffer::<u32>::new(ctx, "densify.action", n.max(1) as usize)?;
        let scratch = ScanScratch::new(ctx, n + 1)?;
        let mut rec = Recorder::new(ctx)?;
        let push = MarkPush {
            n,
            grow: p.grow as u32,
            prune_big: p.prune_big as u32,
            pad: 0,
            grad_threshold: p.grad_threshold,
            dense_scale: p.dense_scale,
            opacity_min: p.opacity_min,
            big_world: p.big_world,
            big_screen: p.big_screen,
        };
        let g = &set.params;
        rec.dispatch(
            &self.mark,
            &[g.opacity.binding(), g.log_scales.binding(), set.accum.binding(), set.denom.binding(), set.max_radii.binding(), counts.binding(), action.binding()],
            bytemuck::bytes_of(&push),
            grid(ctx, n + 1),
        )?;
        self.scan.record(&mut rec, &counts, &counts, &Count::Host(n + 1), &scratch)?;
        rec.submit_and_wait()?;
        let total = counts.download_range(n as usize, 1)?[0];

        let (c, k) = (g.channels, g.coeffs);
        // densify_apply writes every element of the new buffers.
        let (params, m, v) = (Gaussians::uninit(ctx, total, c, k)?, Gaussians::uninit(ctx, total, c, k)?, Gaussians::uninit(ctx, total, c, k)?);
        let mut rec = Recorder::new(ctx)?;
        let f = (c * k) as usize;
        // The output offsets, read back only when an array is copied in
        // slices (the SH 3 features of a million Gaussians: 183 MiB).
        let mut offsets: Option<Vec<u32>> = None;
        // Modes of densify/apply.comp: 0 moments, 1 copy, 2 means, 3 log-scales.
        for (src, dst, is_param) in [(&set.params, &params, true), (&set.m, &m, false), (&set.v, &v, false)] {
            let mode = is_param as u32;
            // Parameters: means and log-scales have modes of their own.
            let modes = if is_param { [2, 3, mode, mode, mode] } else { [mode; 5] };
            let arrays = src.buffers().into_iter().zip(dst.buffers()).zip(crate::raster::array_widths(f)).zip(modes);
            for (((s, d), width), mode) in arrays {
                let width = width as u32;
                let per = self.copy_slice(n, total, width);
                let bind = |src: BufferBinding, dst: BufferBinding| [src, dst, counts.binding(), action.binding(), g.log_scales.binding(), g.quats.binding()];
                if per >= n {
                    let push = [n, width, mode, p.seed, 0, 0];
                    rec.dispatch(&self.apply, &bind(s.binding(), d.binding()), bytemuck::cast_slice(&push), grid(ctx, n))?;
                    continue;
                }
                if offsets.is_none() {
                    offsets = Some(counts.download()?);
                }
                let o = offsets.as_ref().expect("offsets read back");
                let align_f = (ctx.caps().min_storage_buffer_offset_alignment / 4).max(1) as u32;
                for a in (0..n).step_by(per as usize) {
                    let b = (a + per).min(n);
                    if o[b as usize] == o[a as usize] {
                        continue; // every source of the slice pruned
                    }
                    // The slice's outputs start at o[a]; bound from the
                    // aligned float at or before it.
                    let start = o[a as usize] * width / align_f * align_f;
                    let end = o[b as usize] * width;
                    let push = [b, width, mode, p.seed, a, start];
                    let bindings = bind(s.slice((a * width) as usize, ((b - a) * width) as usize), d.slice(start as usize, (end - start) as usize));
                    rec.dispatch(&self.apply, &bindings, bytemuck::cast_slice(&push), grid(ctx, b - a))?;
                }
            }
        }
        rec.submit_and_wait()?;
        *set = TrainableSet::from_parts(ctx, params, m, v)?;
        Ok(DensifyReport { before: n, after: total })
    }
}
