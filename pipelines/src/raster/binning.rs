//! Tile binning, the first half of a view's forward: projection of every
//! Gaussian, the depth sort, per-Gaussian tile counts and their prefix sum,
//! the plan of the emission (capacity check, indirect arguments), emission
//! of one (tile, depth) key per intersection, the stable tile sort, and
//! each tile's range of intersections. Counts stay on the GPU.

use super::{Frame, Gaussians, Push, Rasterizer};
use crate::scan::Count;
use crate::WG;
use anyhow::{Context as _, Result};
use tgs_engine::{Buffer, Kernel, Recorder};

impl Rasterizer {
    /// Record the binning of the Gaussians `g` (features `features`) into
    /// `frame`, with the forward's push constants `push`.
    pub(super) fn record_binning(&self, rec: &mut Recorder, g: &Gaussians, features: &Buffer<f32>, push: &Push, frame: &Frame) -> Result<()> {
        self.record_project(rec, g, features, push, frame)?;
        self.record_bins(rec, g.n, push, frame)
    }

    /// The projection alone: every Gaussian's splat, colour, tile rectangle
    /// and depth key (the rest of the binning reads them; a kept view
    /// needs only the splats and colours, `kept.rs`).
    pub(super) fn record_project(&self, rec: &mut Recorder, g: &Gaussians, features: &Buffer<f32>, push: &Push, frame: &Frame) -> Result<()> {
        self.record_project_with(rec, &self.tile_kernels(frame.tile)?.project, true, g, features, push, frame)
    }

    /// [`Rasterizer::record_project`] with `project`: the kernel
    /// (`geometry`), or its variant that writes the colours alone and
    /// declares the bindings up to theirs (kept_weights.rs).
    #[allow(clippy::too_many_arguments)] // the kernel's bindings, each its own input
    pub(super) fn record_project_with(
        &self,
        rec: &mut Recorder,
        project: &Kernel,
        geometry: bool,
        g: &Gaussians,
        features: &Buffer<f32>,
        push: &Push,
        frame: &Frame,
    ) -> Result<()> {
        let sc = rec.begin_scope("raster.project");
        for slice in self.feature_slices(g.n) {
            let mut bindings = self.param_bindings(frame, g, features, slice);
            bindings.extend([frame.proj.binding(), frame.pfeat.binding()]);
            if geometry {
                bindings.extend([
                    frame.rects.binding(),
                    frame.tiles.binding(),
                    frame.depth_keys.binding(),
                    frame.depth_ids.binding(),
                    frame.radii.binding(),
                    frame.tile_masks.binding(),
                ]);
            }
            let p = Push { feat_base: slice.0, feat_end: slice.1, ..*push };
            let count = slice.1.min(g.n) - slice.0;
            rec.dispatch(project, &bindings, bytemuck::bytes_of(&p), self.groups(count))?;
        }
        rec.end_scope(sc);
        Ok(())
    }

    /// The binning after the projection of `n` Gaussians.
    fn record_bins(&self, rec: &mut Recorder, n: u32, push: &Push, frame: &Frame) -> Result<()> {
        let sc = rec.begin_scope("raster.depth_sort");
        self.sort.record(rec, &frame.depth_keys, &frame.depth_ids, &Count::Host(n), 32, &frame.depth_scratch).context("depth sort")?;
        rec.end_scope(sc);

        let sc = rec.begin_scope("raster.gather");
        rec.dispatch(&self.gather, &[frame.depth_ids.binding(), frame.tiles.binding(), frame.offsets.binding()], bytemuck::bytes_of(&n), self.groups(n + 1))?;
        rec.end_scope(sc);
        let sc = rec.begin_scope("raster.scan");
        self.scan.record(rec, &frame.offsets, &frame.offsets, &Count::Host(n + 1), &frame.scan_scratch)?;
        rec.end_scope(sc);

        let sc = rec.begin_scope("raster.plan");
        let plan_push = [n, frame.capacity, WG, self.max_x()];
        rec.dispatch(&self.plan, &[frame.offsets.binding(), frame.params.binding(), frame.args.binding(), frame.stats.binding()], bytemuck::cast_slice(&plan_push), [1, 1, 1])?;
        rec.end_scope(sc);

        let sc = rec.begin_scope("raster.emit");
        rec.dispatch(
            &self.tile_kernels(frame.tile)?.emit,
            &[
                frame.depth_ids.binding(),
                frame.offsets.binding(),
                frame.rects.binding(),
                frame.isect_keys.binding(),
                frame.isect_vals.binding(),
                frame.isect_gid.binding(),
                frame.proj.binding(),
                frame.tile_masks.binding(),
            ],
            bytemuck::bytes_of(push),
            self.groups(n),
        )?;
        rec.end_scope(sc);

        let tiles = frame.tiles();
        let tile_bits = 32 - (tiles.max(1) - 1).leading_zeros();
        let count = Count::Gpu { buffer: frame.params.binding(), index: 0 };
        let sc = rec.begin_scope("raster.tile_sort");
        self.sort.record(rec, &frame.isect_keys, &frame.isect_vals, &count, tile_bits, &frame.tile_scratch).context("tile sort")?;
        rec.end_scope(sc);

        let sc = rec.begin_scope("raster.ranges");
        rec.fill(&frame.ranges.binding(), 0)?;
        rec.dispatch_indirect(&self.ranges, &[frame.params.binding(), frame.isect_keys.binding(), frame.ranges.binding()], &[], &frame.args.binding())?;
        rec.end_scope(sc);
        Ok(())
    }
}
