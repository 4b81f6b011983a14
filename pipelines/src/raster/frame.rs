//! Per-view working memory of the rasterizer: projected splats, binning,
//! per-pixel outputs and state, and the per-intersection gradient slots.
//!
//! Capacities are fixed when recorded (nothing is read back inside an
//! iteration). After the GPU work ran, [`crate::Rasterizer::fit`] reads two
//! counters back (8 bytes) and grows the frame when the intersections or the
//! longest tile outgrew it; the caller then re-runs that view.

use crate::scan::ScanScratch;
use crate::sort::SortScratch;
use anyhow::Result;
use tgs_engine::{Buffer, Readback};

/// Output planes, each `width * height` floats, in this order.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Plane {
    /// Feature channel c (colour with the background blended in).
    Feature(u32),
    /// 1 - final transmittance.
    Alpha,
    /// Sum of w_i z_i (divide by alpha for the expected depth).
    Depth,
    /// Component k of the blended view-space normal (unnormalised).
    Normal(u32),
    /// Depth of the splat where transmittance crossed 0.5 (0 if none).
    Median,
    /// Depth distortion, sum_ij w_i w_j (m_i - m_j)^2 on NDC-mapped depth.
    Distortion,
}

impl Plane {
    /// Index of the plane for `channels` feature channels.
    pub fn index(self, channels: u32) -> u32 {
        match self {
            Plane::Feature(c) => c,
            Plane::Alpha => channels,
            Plane::Depth => channels + 1,
            Plane::Normal(k) => channels + 2 + k,
            Plane::Median => channels + 5,
            Plane::Distortion => channels + 6,
        }
    }
    /// Number of output planes for `channels` feature channels.
    pub fn count(channels: u32) -> u32 {
        channels + 7
    }
}

pub struct Frame {
    pub width: u32,
    pub height: u32,
    /// Tile side in pixels (8 or 16: the rasterizer's choice for the size).
    pub tile: u32,
    pub tiles_x: u32,
    pub tiles_y: u32,
    /// Gaussians this frame can take.
    pub max_gaussians: u32,
    /// Intersections this frame can take.
    pub capacity: u32,
    /// Span passes recorded per view (tiles longer than spans * span need more).
    pub spans: u32,
    /// The intersection total of the last run (after `fit`).
    pub last_intersections: u32,
    pub(crate) cam: Buffer<f32>,
    pub(crate) proj: Buffer<f32>,
    pub(crate) pfeat: Buffer<f32>,
    pub(crate) rects: Buffer<u32>,
    pub(crate) tiles: Buffer<u32>,
    /// Which tiles of its rectangle each Gaussian reaches, a bit a tile in
    /// row order (four words), where the rectangle has at most 128
    /// (raster/tile_cull.glsl `MASK_TILES`).
    pub(crate) tile_masks: Buffer<u32>,
    pub(crate) depth_keys: Buffer<u32>,
    pub(crate) depth_ids: Buffer<u32>,
    pub(crate) depth_scratch: SortScratch,
    pub(crate) offsets: Buffer<u32>,
    pub(crate) scan_scratch: ScanScratch,
    pub(crate) params: Buffer<u32>,
    pub(crate) args: Buffer<u32>,
    pub(crate) stats: Buffer<u32>,
    /// `stats` as the last submitted forward left it (read by `fit`).
    pub(crate) stats_host: Readback<u32>,
    /// Indirect arguments written by `Rasterizer::record_fit_gate`.
    pub(crate) gate: Buffer<u32>,
    pub(crate) isect_keys: Buffer<u32>,
    pub(crate) isect_vals: Buffer<u32>,
    pub(crate) isect_gid: Buffer<u32>,
    pub(crate) tile_scratch: SortScratch,
    pub(crate) ranges: Buffer<u32>,
    /// Output planes (see [`Plane`]).
    pub out: Buffer<f32>,
    /// Upstream gradient of the loss with respect to every output plane
    /// (same layout as `out`); written by the caller before the backward.
    pub grad_out: Buffer<f32>,
    pub(crate) fstate: Buffer<f32>,
    pub(crate) ustate: Buffer<u32>,
    pub(crate) bstate: Buffer<f32>,
    pub(crate) isect_grads: Buffer<f32>,
    /// The records' device address (two u32, low first) when the rasterizer
    /// reaches them by address ([`super::RecordAccess::Address`]).
    pub(crate) records_address: Option<Buffer<u32>>,
    /// Screen-space gradient per Gaussian (2 floats, NDC units) from the last backward.
    pub densify: Buffer<f32>,
    /// Screen radius in pixels per Gaussian from the last forward (0 = culled).
    pub radii: Buffer<f32>,
}

impl Frame {
    /// The indirect arguments the last `Rasterizer::record_fit_gate` wrote
    /// (3 per gated dispatch), downloaded.
    pub fn gate_args(&self) -> Result<Vec<u32>> {
        self.gate.download()
    }

    /// Tile rectangles [x0, y0, x1, y1) of the first `n` Gaussians from the
    /// last forward (empty for culled ones). One read-back, for inspection.
    pub fn download_rects(&self, n: usize) -> anyhow::Result<Vec<[u32; 4]>> {
        Ok(self.rects.download_range(0, 4 * n)?.chunks(4).map(|c| [c[0], c[1], c[2], c[3]]).collect())
    }
    /// Pixel boxes [x_lo, y_lo, x_hi, y_hi] of the first `n` Gaussians from
    /// the last forward: the tile kernels evaluate a splat only at pixel
    /// centres inside its box (glsl/raster/project.glsl `pixel_box`;
    /// +-3e38 where the splat is unbounded on screen, undefined for culled
    /// ones). One read-back, for inspection.
    pub fn download_pixel_boxes(&self, n: usize) -> anyhow::Result<Vec<[f32; 4]>> {
        let stride = super::PROJ_STRIDE;
        let proj = self.proj.download_range(0, stride * n)?;
        Ok(proj.chunks(stride).map(|c| [c[16], c[17], c[18], c[19]]).collect())
    }
    /// (tile, Gaussian) of every intersection of the last forward, in the
    /// tile-sorted order the tile kernels read (tiles ascending, each
    /// tile's splats front to back). One read-back, for inspection.
    pub fn download_intersections(&self) -> anyhow::Result<Vec<(u32, u32)>> {
        let m = self.last_intersections.min(self.capacity) as usize;
        if m == 0 {
            return Ok(Vec::new());
        }
        let (keys, vals, gid) = (self.isect_keys.download_range(0, m)?, self.isect_vals.download_range(0, m)?, self.isect_gid.download_range(0, m)?);
        Ok(keys.iter().zip(&vals).map(|(&k, &v)| (k, gid[v as usize])).collect())
    }
    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }
    pub fn tiles(&self) -> u32 {
        self.tiles_x * self.tiles_y
    }
}
