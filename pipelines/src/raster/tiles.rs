//! The kernels that depend on the tile size: the projection (its tile
//! rectangles) and the per-tile forward and backward (pixels per
//! invocation), with the span that keeps their loops within a CPU driver's
//! limit. A rasterizer builds a set per tile size on first use: the
//! Workgroup kernels (GPUs) use 16 x 16 tiles (one pixel per invocation of
//! 256); the Subgroup kernels (CPU drivers) 8 x 8 wherever a frame's tile
//! count fits the loop budget, else 16 x 16 (`TGS_RASTER_TILE=16` keeps
//! them at 16 x 16). A splat is walked by every pixel of every tile it is
//! binned to; with tiles a quarter the size a small splat costs about a
//! quarter as much per tile for about 1.3x the intersections (measured on
//! llvmpipe, perf/RESULTS.md thirty-fifth entry: the forward 2.2x and the
//! backward 1.3x faster at the README's main job's scale on random
//! spheres; on a trained model of 33k Gaussians, 1.7x the intersections,
//! the forward 19% faster, the backward 3-5% slower, a Stage I iteration
//! 4-6% faster; Stage II and early Stage I gain more, thirty-seventh
//! entry). The image does
//! not depend on the tile size: a splat is evaluated only inside its pixel
//! box, and one unbounded on screen is binned to every tile; only the
//! backward's summation order does (thirty-sixth entry).

use super::{Push, RasterKernels, RecordAccess, LOOP_BUDGET, SPAN_STEP, WG};
use crate::shaders;
use anyhow::Result;
use std::sync::{Arc, OnceLock};
use tgs_engine::{Context, Kernel, KernelDesc};

/// The Workgroup kernels' tile side (their workgroup is its square).
pub(super) const WIDE_TILE: u32 = 16;
/// The Subgroup kernels' tile side where the frame allows it.
pub(super) const SMALL_TILE: u32 = 8;

/// What the tile kernels are specialized for (the rasterizer's settings).
#[derive(Clone, Copy)]
pub(super) struct TileSpec {
    pub(super) kernels: RasterKernels,
    pub(super) records: RecordAccess,
    pub(super) channels: u32,
    pub(super) batch: u32,
    /// The span when forced (tests), else from the loop budget.
    pub(super) span: Option<u32>,
    /// Whether frames may use SMALL_TILE (unless `TGS_RASTER_TILE=16`,
    /// read once when the rasterizer is made: [`TileSpec::small_tiles_allowed`]).
    pub(super) small: bool,
}

pub(super) struct TileKernels {
    pub(super) project: Kernel,
    /// The emission of each splat's tiles (it tests them at this tile side).
    pub(super) emit: Kernel,
    pub(super) forward: Kernel,
    pub(super) backward: Kernel,
    /// The feature-only backward and the colour-only forward (variant
    /// COLOUR_ONLY of each), built on first use.
    backward_colour: OnceLock<Kernel>,
    forward_colour: OnceLock<Kernel>,
    /// The tile kernels' specialization (the forward's and backward's, for the colour ones).
    spec: Vec<(u32, u32)>,
    ctx: Arc<Context>,
    /// SPIR-V of the two colour kernels.
    backward_colour_spirv: &'static [u8],
    forward_colour_spirv: &'static [u8],
    /// Whether the forwards need full subgroups (the Subgroup kernels).
    full_forward: bool,
}

impl TileSpec {
    /// Pixels per invocation of the Subgroup kernels with `tile` x `tile`
    /// tiles on a device of subgroup `sg`.
    fn ppt(tile: u32, sg: u32) -> u32 {
        (tile * tile / sg.max(1)).max(1)
    }

    /// Splats per span with `tile` x `tile` tiles.
    pub(super) fn span(&self, caps: &tgs_engine::Capabilities, tile: u32) -> u32 {
        if let Some(s) = self.span {
            return s;
        }
        if !caps.is_cpu() {
            return u32::MAX / 2 / WG * WG;
        }
        // Loop iterations per splat in the forward and the backward (every
        // loop counted, unrolled or not).
        let ch = self.channels as f64;
        let krec = (15 + self.channels) as f64;
        let max_sg_count = (WG / caps.min_subgroup_size.max(1)) as f64;
        let (batch, ppt) = (self.batch as f64, Self::ppt(tile, caps.subgroup_size) as f64);
        let (fwd, bwd) = match self.kernels {
            RasterKernels::Workgroup => (2.0 + ch, 3.0 + 2.0 * ch + (((batch * krec) / WG as f64).ceil() * (1.0 + max_sg_count) + 1.0) / batch),
            RasterKernels::Subgroup => (ppt * (1.0 + ch) + ch + 2.0, ppt * (1.0 + ch) + 3.0 * ch + 2.0),
        };
        let s = (LOOP_BUDGET / fwd.max(bwd)) as u32 / SPAN_STEP * SPAN_STEP;
        s.max(SPAN_STEP)
    }

    /// The tile side a `width` x `height` frame uses: SMALL_TILE for the
    /// Subgroup kernels where its tiles fit the loop budget of a CPU driver
    /// (`fits`) and `TGS_RASTER_TILE=16` does not ask otherwise, else
    /// WIDE_TILE.
    pub(super) fn tile_for(&self, width: u32, height: u32, fits: impl Fn(u64) -> bool) -> u32 {
        let tiles = width.div_ceil(SMALL_TILE) as u64 * height.div_ceil(SMALL_TILE) as u64;
        if self.small && self.kernels == RasterKernels::Subgroup && fits(tiles) {
            SMALL_TILE
        } else {
            WIDE_TILE
        }
    }

    /// SMALL_TILE unless `TGS_RASTER_TILE=16` (scripts/test.sh runs the
    /// kernel suites' second pass with it, so both sizes are tested);
    /// `8` or unset allows it, any other value is refused.
    pub(super) fn small_tiles_allowed() -> Result<bool> {
        small_tiles_from(std::env::var("TGS_RASTER_TILE").ok().as_deref())
    }

    pub(super) fn build(&self, ctx: &Arc<Context>, tile: u32) -> Result<TileKernels> {
        let caps = ctx.caps();
        let min_sg = caps.min_subgroup_size.max(1);
        let push = std::mem::size_of::<Push>() as u32;
        let by_address = self.records == RecordAccess::Address;
        let (ch, batch) = (self.channels, self.batch);
        let common = [(0, WG), (1, min_sg), (4, ch), (5, batch), (7, tile)];
        let spec = match self.kernels {
            RasterKernels::Workgroup => common.to_vec(),
            RasterKernels::Subgroup => {
                let sg = caps.subgroup_size;
                vec![(0, sg), (1, sg), (4, ch), (5, batch), (6, Self::ppt(tile, sg)), (7, tile)]
            }
        };
        let k = |name, spirv, spec: &[(u32, u32)], full| Kernel::new(ctx, &KernelDesc { name, spirv, spec, push_bytes: push, subgroup_size: None, full_subgroups: full });
        let (fwd, bwd, colour) = match (self.kernels, by_address) {
            (RasterKernels::Workgroup, false) => (shaders::RASTER_FORWARD, shaders::RASTER_BACKWARD, shaders::RASTER_BACKWARD_COLOUR_ONLY),
            (RasterKernels::Workgroup, true) => (shaders::RASTER_FORWARD, shaders::RASTER_BACKWARD_RECORDS_BDA, shaders::RASTER_BACKWARD_COLOUR_ONLY_RECORDS_BDA),
            (RasterKernels::Subgroup, false) => (shaders::RASTER_FORWARD_SG, shaders::RASTER_BACKWARD_SG, shaders::RASTER_BACKWARD_SG_COLOUR_ONLY),
            (RasterKernels::Subgroup, true) => (shaders::RASTER_FORWARD_SG, shaders::RASTER_BACKWARD_SG_RECORDS_BDA, shaders::RASTER_BACKWARD_SG_COLOUR_ONLY_RECORDS_BDA),
        };
        let fwd_colour = match self.kernels {
            RasterKernels::Workgroup => shaders::RASTER_FORWARD_COLOUR_ONLY,
            RasterKernels::Subgroup => shaders::RASTER_FORWARD_SG_COLOUR_ONLY,
        };
        // The Subgroup kernels' projection reads the Gaussians as texel
        // buffers (one gather a load on llvmpipe, where a storage load
        // loops over the lanes).
        let project = match self.kernels {
            RasterKernels::Workgroup => shaders::RASTER_PROJECT,
            RasterKernels::Subgroup => shaders::RASTER_PROJECT_TEXEL,
        };
        let full_forward = self.kernels == RasterKernels::Subgroup;
        Ok(TileKernels {
            project: k("raster.project", project, &common, false)?,
            emit: k("raster.emit", shaders::RASTER_EMIT, &common, false)?,
            forward: k("raster.forward", fwd, &spec, full_forward)?,
            backward: k("raster.backward", bwd, &spec, true)?,
            backward_colour: OnceLock::new(),
            forward_colour: OnceLock::new(),
            spec,
            ctx: ctx.clone(),
            backward_colour_spirv: colour,
            forward_colour_spirv: fwd_colour,
            full_forward,
        })
    }
}

impl TileKernels {
    pub(super) fn backward_colour(&self) -> Result<&Kernel> {
        self.colour_kernel(&self.backward_colour, "raster.backward", self.backward_colour_spirv, true)
    }

    /// The forward that writes the features and alpha alone (a final image).
    pub(super) fn forward_colour(&self) -> Result<&Kernel> {
        self.colour_kernel(&self.forward_colour, "raster.forward", self.forward_colour_spirv, self.full_forward)
    }

    fn colour_kernel<'a>(&self, cell: &'a OnceLock<Kernel>, name: &str, spirv: &[u8], full_subgroups: bool) -> Result<&'a Kernel> {
        if let Some(k) = cell.get() {
            return Ok(k);
        }
        let push_bytes = std::mem::size_of::<Push>() as u32;
        let k = Kernel::new(&self.ctx, &KernelDesc { name, spirv, spec: &self.spec, push_bytes, subgroup_size: None, full_subgroups })?;
        Ok(cell.get_or_init(|| k))
    }
}

/// [`TileSpec::small_tiles_allowed`] for the variable's value.
fn small_tiles_from(value: Option<&str>) -> Result<bool> {
    match value.map(str::trim) {
        None | Some("8") => Ok(true),
        Some("16") => Ok(false),
        Some(other) => anyhow::bail!("TGS_RASTER_TILE must be 8 or 16 (the CPU rasterizer's tile side), not {other:?}"),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_tile_variable_is_8_16_or_unset() {
        assert!(super::small_tiles_from(None).unwrap());
        assert!(super::small_tiles_from(Some("8")).unwrap());
        assert!(!super::small_tiles_from(Some(" 16 ")).unwrap());
        for bad in ["", "32", "auto"] {
            let e = super::small_tiles_from(Some(bad)).unwrap_err().to_string();
            assert!(e.contains("TGS_RASTER_TILE") && e.contains(&format!("{bad:?}")), "{e}");
        }
    }
}
