//! The per-pixel forward of a view (after binning: each tile's splats
//! front to back, span by span), the fit gate that lets one submission hold
//! a whole training iteration, and the capacity check that grows a frame
//! when a view did not fit.

use super::{Camera, Frame, Gaussians, IntersectionBuffers, Push, Rasterizer, RecordAccess, Splats, GATE_PUSH_WORDS, GATE_SLOTS};
use anyhow::{bail, Result};
use tgs_engine::{groups_2d, Buffer, BufferBinding, Recorder};

impl Rasterizer {
    /// Record the forward pass of one view: outputs land in `frame.out`.
    /// `sh_degree` is the active SH degree (ignored for plain features).
    pub fn record_forward(&self, rec: &mut Recorder, g: &Gaussians, cam: &Camera, background: &[f32], sh_degree: u32, frame: &Frame) -> Result<()> {
        self.record_forward_with(rec, Splats::own(g, sh_degree), cam, background, frame)
    }

    /// As [`Rasterizer::record_forward`], with the per-Gaussian features
    /// taken from `s.features` (this rasterizer's channels x coefficients
    /// per Gaussian), which may be another kernel's instead of the set's
    /// own (e.g. the reflection colour).
    pub fn record_forward_with(&self, rec: &mut Recorder, s: Splats, cam: &Camera, background: &[f32], frame: &Frame) -> Result<()> {
        self.record_forward_of(rec, s, cam, background, frame, false)
    }

    /// As [`Rasterizer::record_forward`] for a final image: the feature
    /// planes and alpha, bit for bit the full forward's, and nothing else
    /// (the depth, normal, median and distortion planes keep what they
    /// held; no backward may read the frame). Cheaper per pixel
    /// (glsl/raster/pixel_blend.glsl).
    pub fn record_forward_colour(&self, rec: &mut Recorder, g: &Gaussians, cam: &Camera, background: &[f32], sh_degree: u32, frame: &Frame) -> Result<()> {
        self.record_forward_of(rec, Splats::own(g, sh_degree), cam, background, frame, true)
    }

    /// Binning, then the tiles' forward (`colour_only`: its COLOUR_ONLY kernel).
    fn record_forward_of(&self, rec: &mut Recorder, s: Splats, cam: &Camera, background: &[f32], frame: &Frame, colour_only: bool) -> Result<()> {
        let push = self.begin_forward(rec, &s, cam, background, frame)?;
        self.record_binning(rec, s.g, s.features, &push, frame)?;
        self.record_tiles_forward(rec, &push, frame, colour_only)
    }

    /// A view's forward up to its binning: the inputs checked, the camera
    /// written; returns the forward's push constants.
    pub(super) fn begin_forward(&self, rec: &mut Recorder, s: &Splats, cam: &Camera, background: &[f32], frame: &Frame) -> Result<Push> {
        let Splats { g, features, sh_degree } = *s;
        self.check_inputs(g, features, frame)?;
        cam.validate()?;
        if cam.width != frame.width || cam.height != frame.height {
            bail!("camera is {}x{} but the frame is {}x{}", cam.width, cam.height, frame.width, frame.height);
        }
        if background.len() != self.channels as usize {
            bail!("background has {} values; the rasterizer has {} channels", background.len(), self.channels);
        }
        let push = self.push(g, frame, sh_degree);
        rec.update(&frame.cam.binding(), bytemuck::cast_slice(&cam.pack(background)))?;
        Ok(push)
    }

    /// A view's forward after its binning: each tile's splats, span by
    /// span (`colour_only`: [`Rasterizer::record_forward_colour`]'s kernel).
    pub(super) fn record_tiles_forward(&self, rec: &mut Recorder, push: &Push, frame: &Frame, colour_only: bool) -> Result<()> {
        let kernels = self.tile_kernels(frame.tile)?;
        let forward = if colour_only { kernels.forward_colour()? } else { &kernels.forward };
        let tiles = frame.tiles();
        let tile_groups = groups_2d(tiles, self.max_x());
        let mut bindings = Self::tile_bindings(frame);
        bindings.push(frame.stats.binding());
        for k in 0..frame.spans {
            let p = Push { span_index: k, ..*push };
            let sc = rec.begin_scope("raster.forward");
            rec.dispatch(forward, &bindings, bytemuck::bytes_of(&p), tile_groups)?;
            rec.end_scope(sc);
        }
        // The total and the overflow flag ride this submission back to the host (`fit`).
        rec.read_back(&frame.stats, 0, &frame.stats_host)
    }

    /// Record, after the forward of `frame` (same recording), indirect
    /// arguments for up to [`GATE_SLOTS`] later dispatches: `grids[k]` when
    /// the view fitted its frame, zero workgroups when it overflowed (see
    /// [`Rasterizer::fit`]). Returns the argument slot of each grid, for
    /// `Recorder::dispatch_indirect`. This is how one submission can hold a
    /// whole training iteration: an overflowed view updates nothing, and the
    /// host grows the frame and runs the iteration again.
    pub fn record_fit_gate(&self, rec: &mut Recorder, frame: &Frame, grids: &[[u32; 3]]) -> Result<Vec<BufferBinding>> {
        if grids.len() > GATE_SLOTS {
            bail!("{} gated dispatches; the gate holds {GATE_SLOTS}", grids.len());
        }
        let mut push = [0u32; GATE_PUSH_WORDS];
        push[0] = frame.capacity;
        push[1] = grids.len() as u32;
        for (k, g) in grids.iter().enumerate() {
            push[4 + 3 * k..7 + 3 * k].copy_from_slice(g);
        }
        let sc = rec.begin_scope("raster.gate");
        rec.dispatch(&self.gate, &[frame.stats.binding(), frame.gate.binding()], bytemuck::cast_slice(&push), [1, 1, 1])?;
        rec.end_scope(sc);
        Ok((0..grids.len()).map(|k| frame.gate.slice(3 * k, 3)).collect())
    }

    /// After a recorded view's submission completed: read the intersection
    /// total and the span overflow flag it brought back (no submission).
    /// Returns `true` when everything fitted; otherwise grows `frame` so that
    /// a re-run fits and returns `false`.
    pub fn fit(&self, frame: &mut Frame) -> Result<bool> {
        let stats = frame.stats_host.read()?;
        let (total, span_overflow) = (stats[0], stats[1] != 0);
        frame.last_intersections = total;
        let mut fits = true;
        if total > frame.capacity {
            let max = self.max_capacity();
            if total > max {
                bail!("this view has {total} tile-splat intersections; the device allows at most {max} (fewer or smaller Gaussians, or a smaller image)");
            }
            let cap = (total as u64 + total as u64 / 4).min(max as u64) as u32;
            self.grow(frame, cap)?;
            fits = false;
        }
        if span_overflow {
            let r = frame.ranges.download()?;
            let longest = r.chunks(2).map(|c| c[1].saturating_sub(c[0])).max().unwrap_or(0);
            frame.spans = longest.div_ceil(self.span_of(frame.tile)).max(frame.spans + 1);
            fits = false;
        }
        Ok(fits)
    }

    pub(super) fn grow(&self, frame: &mut Frame, capacity: u32) -> Result<()> {
        (frame.isect_keys, frame.isect_vals, frame.isect_gid, frame.tile_scratch, frame.isect_grads, frame.records_address) = self.intersection_buffers(capacity)?;
        frame.capacity = capacity;
        Ok(())
    }

    /// The per-intersection arrays of a frame (keys, values, Gaussian ids,
    /// tile-sort scratch, gradient records, their address). Emission writes
    /// entries [0, count) and the backward every record of them (zeros past
    /// a tile's last contributor) before anything reads them, so they start
    /// undefined.
    pub(super) fn intersection_buffers(&self, capacity: u32) -> Result<IntersectionBuffers> {
        let (ctx, cap) = (&self.ctx, capacity as usize);
        let records = Buffer::uninit(ctx, "raster.isect_grads", cap * self.record_len() as usize)?;
        let address = match self.records {
            RecordAccess::Binding => None,
            RecordAccess::Address => {
                let a = records.device_address()?;
                Some(Buffer::from_slice(ctx, "raster.records_address", &[a as u32, (a >> 32) as u32])?)
            }
        };
        Ok((
            Buffer::uninit(ctx, "raster.isect_keys", cap)?,
            Buffer::uninit(ctx, "raster.isect_vals", cap)?,
            Buffer::uninit(ctx, "raster.isect_gid", cap)?,
            self.sort.scratch(capacity)?,
            records,
            address,
        ))
    }

    /// Run the forward of one view to completion, growing `frame` and
    /// re-running when it did not fit. Returns the GPU timings of the last run
    /// (empty unless `profile`).
    pub fn forward(&self, g: &Gaussians, cam: &Camera, background: &[f32], sh_degree: u32, frame: &mut Frame, profile: bool) -> Result<Vec<tgs_engine::Timing>> {
        loop {
            let mut rec = Recorder::profiled_if(&self.ctx, profile)?;
            self.record_forward(&mut rec, g, cam, background, sh_degree, frame)?;
            let t = rec.submit_and_wait()?;
            if self.fit(frame)? {
                return Ok(t);
            }
        }
    }
}

#[cfg(test)]
mod gate_layout {
    /// The gate shader's push-constant array is sized by hand: it must hold
    /// x, y, z for every one of GATE_SLOTS slots.
    #[test]
    fn gate_shader_array_matches_gate_slots() {
        let src = include_str!("../../../glsl/raster/gate.comp");
        let want = format!("uint grids[{}];", 3 * super::GATE_SLOTS);
        assert!(src.contains(&want), "glsl/raster/gate.comp should declare `{want}` (3 x GATE_SLOTS)");
    }
}
