//! TSDF fusion for `tgs mesh` (GLSL: `glsl/mesh/tsdf_fuse.comp`): a regular
//! voxel grid of truncated signed distances, weights and colours, updated
//! one view at a time from a depth image, a per-pixel weight image and a
//! colour image. Each voxel has one writer; views are applied in the order
//! they are recorded, so the grid is bit-identical across reruns and
//! subgroup sizes. The f64 reference is `tests/src/tsdf_ref.rs`.

use crate::shaders;
use crate::train::{grid, kernel};
use crate::Camera;
use anyhow::{bail, Result};
use bytemuck::{Pod, Zeroable};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Kernel, Recorder};

/// Bytes of device memory per voxel (TSDF, weight, three colour channels).
pub const BYTES_PER_VOXEL: u64 = 20;

/// A voxel grid: voxel (i, j, k) has its centre at
/// `origin + (i + 0.5, j + 0.5, k + 0.5) * voxel`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TsdfGrid {
    pub origin: [f32; 3],
    pub voxel: f32,
    pub dims: [u32; 3],
    /// Truncation distance (world units): the signed distance is divided by
    /// it and clamped to 1 in front; voxels more than this behind the
    /// observed surface are not updated.
    pub trunc: f32,
    /// Depths past this are not fused (`f32::INFINITY`: no limit).
    pub depth_max: f32,
}

impl TsdfGrid {
    /// The number of voxels (checked: at most u32::MAX).
    pub fn voxels(&self) -> Result<u32> {
        let n = self.dims.iter().map(|&d| d as u64).product::<u64>();
        if n == 0 {
            bail!("a {}x{}x{} voxel grid is empty", self.dims[0], self.dims[1], self.dims[2]);
        }
        u32::try_from(n).map_err(|_| anyhow::anyhow!("a {}x{}x{} voxel grid has {n} voxels, more than 2^32", self.dims[0], self.dims[1], self.dims[2]))
    }

    /// The grid's rules: positive finite voxel and truncation, a positive
    /// maximum depth, a finite origin, 1 to 2^32 voxels.
    pub fn validate(&self) -> Result<()> {
        if !(self.voxel > 0.0 && self.voxel.is_finite()) {
            bail!("voxel size {} must be positive and finite", self.voxel);
        }
        if !(self.trunc > 0.0 && self.trunc.is_finite()) {
            bail!("truncation distance {} must be positive and finite", self.trunc);
        }
        if self.depth_max.is_nan() || self.depth_max <= 0.0 {
            bail!("maximum depth {} must be positive", self.depth_max);
        }
        if self.origin.iter().any(|v| !v.is_finite()) {
            bail!("grid origin {:?} is not finite", self.origin);
        }
        self.voxels()?;
        Ok(())
    }
}

/// The grid's arrays on the device (every voxel starts at TSDF 0, weight 0).
pub struct TsdfVolume {
    pub grid: TsdfGrid,
    tsdf: Buffer<f32>,
    weight: Buffer<f32>,
    rgb: [Buffer<f32>; 3],
}

/// The grid downloaded: per voxel (x fastest, then y, then z).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct HostTsdf {
    pub dims: [u32; 3],
    pub tsdf: Vec<f32>,
    /// Sum of the weights of the views that updated the voxel (0: never seen).
    pub weight: Vec<f32>,
    pub rgb: [Vec<f32>; 3],
}

impl TsdfVolume {
    pub fn download(&self) -> Result<HostTsdf> {
        Ok(HostTsdf {
            dims: self.grid.dims,
            tsdf: self.tsdf.download()?,
            weight: self.weight.download()?,
            rgb: [self.rgb[0].download()?, self.rgb[1].download()?, self.rgb[2].download()?],
        })
    }
}

#[repr(C)]
#[derive(Clone, Copy, Pod, Zeroable)]
struct Push {
    rot: [[f32; 4]; 3],
    fx: f32,
    fy: f32,
    cx: f32,
    cy: f32,
    origin: [f32; 4],
    dims: [u32; 4],
    height: u32,
    trunc: f32,
    depth_max: f32,
    pad: u32,
}

pub struct TsdfFusion {
    ctx: Arc<Context>,
    fuse: Kernel,
}

impl TsdfFusion {
    pub fn new(ctx: &Arc<Context>) -> Result<TsdfFusion> {
        Ok(TsdfFusion { ctx: ctx.clone(), fuse: kernel(ctx, "mesh.tsdf_fuse", shaders::MESH_TSDF_FUSE, std::mem::size_of::<Push>() as u32)? })
    }

    /// Allocate a zeroed volume for `grid`, refused (naming the sizes)
    /// where one of its arrays exceeds the device's storage-buffer range or
    /// the whole exceeds `max_bytes`.
    pub fn volume(&self, grid: TsdfGrid, max_bytes: u64) -> Result<TsdfVolume> {
        // The sizes first (in u64: a grid past 2^32 voxels is named in MiB too).
        let [x, y, z] = grid.dims;
        let n = x as u64 * y as u64 * z as u64;
        let total = n.saturating_mul(BYTES_PER_VOXEL);
        if total > max_bytes {
            bail!(
                "a {x}x{y}x{z} voxel grid (voxel {}) needs {:.1} MiB, over the limit of {:.1} MiB: choose a larger voxel",
                grid.voxel,
                total as f64 / 1048576.0,
                max_bytes as f64 / 1048576.0
            );
        }
        let range = self.ctx.caps().max_storage_buffer_range;
        if n.saturating_mul(4) > range {
            bail!(
                "a {x}x{y}x{z} voxel grid needs {:.1} MiB per array, over this device's storage-buffer range of {:.1} MiB: choose a larger voxel",
                (n * 4) as f64 / 1048576.0,
                range as f64 / 1048576.0
            );
        }
        grid.validate()?;
        let n = n as usize;
        Ok(TsdfVolume {
            grid,
            tsdf: Buffer::new(&self.ctx, "mesh.tsdf", n)?,
            weight: Buffer::new(&self.ctx, "mesh.weight", n)?,
            rgb: [Buffer::new(&self.ctx, "mesh.red", n)?, Buffer::new(&self.ctx, "mesh.green", n)?, Buffer::new(&self.ctx, "mesh.blue", n)?],
        })
    }

    /// Record the fusion of one view: `depth` and `weight` (one value per
    /// pixel, row-major) and `colour` (three planes) of `cam`'s image.
    pub fn record(&self, rec: &mut Recorder, vol: &TsdfVolume, cam: &Camera, depth: &Buffer<f32>, weight: &Buffer<f32>, colour: &Buffer<f32>) -> Result<()> {
        let npix = cam.width as usize * cam.height as usize;
        if npix == 0 {
            bail!("TSDF fusion of an empty {}x{} view", cam.width, cam.height);
        }
        if depth.len() < npix || weight.len() < npix || colour.len() < 3 * npix {
            bail!(
                "TSDF fusion of a {}x{} view: depth {}, weight {}, colour {} values (need {npix}, {npix}, {})",
                cam.width,
                cam.height,
                depth.len(),
                weight.len(),
                colour.len(),
                3 * npix
            );
        }
        let g = &vol.grid;
        let pc = Push {
            rot: cam.world_to_view,
            fx: cam.fx,
            fy: cam.fy,
            cx: cam.cx,
            cy: cam.cy,
            origin: [g.origin[0], g.origin[1], g.origin[2], g.voxel],
            dims: [g.dims[0], g.dims[1], g.dims[2], cam.width],
            height: cam.height,
            trunc: g.trunc,
            depth_max: g.depth_max,
            pad: 0,
        };
        let b = [depth.binding(), weight.binding(), colour.binding(), vol.tsdf.binding(), vol.weight.binding(), vol.rgb[0].binding(), vol.rgb[1].binding(), vol.rgb[2].binding()];
        rec.dispatch(&self.fuse, &b, bytemuck::bytes_of(&pc), grid(&self.ctx, g.voxels()?))
    }
}
