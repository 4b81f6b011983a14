//! `tgs mesh RUN`: meshes of a trained run by TSDF fusion, the way 2DGS
//! extracts its meshes, for the scene and, on its own, for the glass.
//!
//! - `mesh_scene.ply`: the scattering set's median depth (the depth where
//!   a pixel's transmittance crosses 0.5) over the training views, fused
//!   into a TSDF on the GPU (`glsl/mesh/tsdf_fuse.comp`), with the
//!   scattering set's colour; weight 1 per view that sees a surface.
//! - `mesh_glass.ply` (when the run has a reflection set, after Stage II):
//!   the reflection set's median depth where it covers the pixel (alpha
//!   >= 0.5), weighted by its alpha, with the rendered colour.
//!
//! The zero level set is extracted by marching tetrahedra ([`extract`]).
//! The grid spans the 1st to 99th percentiles of the surface points the
//! views see (so that stray splats far out do not stretch it), widened by
//! 5% per side; its voxel is, unless given, the footprint of two pixels at
//! the surfaces' median depth (finer says nothing the images can support),
//! or the longest side over `resolution` if that is coarser; the
//! truncation 4 voxels unless given. A grid whose arrays do not
//! fit the memory limit or the device is refused, naming its size.

pub mod extract;
pub mod ply;

use crate::outdir::OutDir;
use crate::train::run::open_run;
use crate::train::Trainer;
use anyhow::{bail, Context as _, Result};
pub use extract::{extract, Mesh};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use tgs_engine::{Buffer, Context, Recorder};
use tgs_pipelines::{Camera, Plane, TsdfFusion, TsdfGrid, TsdfVolume, BYTES_PER_VOXEL};

/// What `tgs mesh` is asked for.
#[derive(Clone, Debug)]
pub struct MeshArgs {
    /// Voxel size in world units (None: two pixels' footprint at the
    /// median depth, at most `resolution` voxels along the longest side).
    pub voxel: Option<f32>,
    /// Most voxels along the grid's longest side when `voxel` is None.
    pub resolution: u32,
    /// Truncation distance (None: 4 voxels).
    pub trunc: Option<f32>,
    /// Depths past this are not fused (None: no limit).
    pub depth_max: Option<f32>,
    /// Largest grid, in bytes of device memory (20 bytes a voxel).
    pub max_bytes: u64,
    /// Where the PLY files go (None: the run directory).
    pub out: Option<PathBuf>,
    pub progress: bool,
}

impl Default for MeshArgs {
    fn default() -> Self {
        MeshArgs { voxel: None, resolution: 512, trunc: None, depth_max: None, max_bytes: 2 << 30, out: None, progress: false }
    }
}

/// One mesh written.
#[derive(Clone, Debug)]
pub struct MeshReport {
    pub path: PathBuf,
    pub grid: TsdfGrid,
    pub mesh: Mesh,
}

/// A view's depth, weight and colour (three) planes.
type Planes = (Vec<f32>, Vec<f32>, Vec<f32>);

/// One render of `cam`, read as both surfaces' planes: the scene's, and the
/// glass's when the run renders a reflection layer.
fn view_planes(tr: &mut Trainer, cam: &Camera) -> Result<(Planes, Option<Planes>)> {
    let r = tr.render(cam)?;
    let n = (cam.width * cam.height) as usize;
    let s = r.layers.as_ref().map(|l| &l.0).unwrap_or(&r);
    let depth = s.plane(Plane::Median).to_vec();
    let weight = depth.iter().map(|&d| if d > 0.0 && d.is_finite() { 1.0 } else { 0.0 }).collect();
    let scene = (depth, weight, s.planes[..3 * n].to_vec());
    let glass = r.layers.as_ref().map(|l| {
        let (depth, alpha) = (l.1.refl_plane(Plane::Median), l.1.refl_plane(Plane::Alpha));
        let weight = (0..n).map(|i| if depth[i] > 0.0 && depth[i].is_finite() && alpha[i] >= 0.5 { alpha[i] } else { 0.0 }).collect();
        (depth.to_vec(), weight, l.1.composite[..3 * n].to_vec())
    });
    Ok((scene, glass))
}

/// The surfaces the views see: the 1st and 99th percentiles per axis of
/// their points (every pixel with weight, up to about 20,000 a view), and
/// the median footprint of a pixel there (depth / focal length).
pub struct Extent {
    pub lo: [f32; 3],
    pub hi: [f32; 3],
    pub pixel: f32,
}

/// A surface's sampled points and pixel footprints, gathered view by view.
#[derive(Default)]
struct Points {
    axes: [Vec<f32>; 3],
    footprint: Vec<f32>,
}

impl Points {
    fn add(&mut self, cam: &Camera, (depth, weight, _): &Planes, depth_max: f32) {
        let n = depth.len();
        let step = n.div_ceil(20_000).max(1);
        for i in (0..n).step_by(step) {
            if weight[i] > 0.0 && depth[i] <= depth_max {
                let p = cam.unproject((i % cam.width as usize) as f32, (i / cam.width as usize) as f32, depth[i]);
                if p.iter().all(|v| v.is_finite()) {
                    for (axis, v) in self.axes.iter_mut().zip(p) {
                        axis.push(v);
                    }
                    self.footprint.push(depth[i] / cam.fx.max(cam.fy));
                }
            }
        }
    }

    fn extent(mut self) -> Option<Extent> {
        if self.axes[0].is_empty() {
            return None;
        }
        let mut lo = [0f32; 3];
        let mut hi = [0f32; 3];
        for k in 0..3 {
            let a = &mut self.axes[k];
            a.sort_by(f32::total_cmp);
            let q = |f: f64| a[((a.len() - 1) as f64 * f).round() as usize];
            lo[k] = q(0.01);
            hi[k] = q(0.99);
        }
        self.footprint.sort_by(f32::total_cmp);
        Some(Extent { lo, hi, pixel: self.footprint[self.footprint.len() / 2] })
    }
}

/// One pass over the views: the scene's extent and, when the run renders
/// a reflection layer, the glass's.
fn bounds(tr: &mut Trainer, cams: &[Camera], depth_max: f32) -> Result<(Option<Extent>, Option<Extent>)> {
    let (mut scene, mut glass) = (Points::default(), None::<Points>);
    for cam in cams {
        let (s, g) = view_planes(tr, cam)?;
        scene.add(cam, &s, depth_max);
        if let Some(g) = g {
            glass.get_or_insert_with(Points::default).add(cam, &g, depth_max);
        }
    }
    Ok((scene.extent(), glass.and_then(Points::extent)))
}

/// The grid over the extent (widened by 5% a side) for `args`.
pub fn grid_for(e: &Extent, args: &MeshArgs) -> Result<TsdfGrid> {
    let (lo, hi) = (e.lo, e.hi);
    let side = (0..3).map(|k| hi[k] - lo[k]).fold(0.0f32, f32::max);
    let voxel = match args.voxel {
        // Fewer than two voxels across the surfaces leaves no surface to extract.
        Some(v) if side > 0.0 && v > 0.5 * side => bail!("--voxel {v:e}: larger than half the surfaces' box ({side:.4} along its longest side), so the mesh would be empty; give at most {:.4} (or leave --voxel out: two pixels' footprint)", 0.5 * side),
        Some(v) => v,
        None => {
            // Two pixels' footprint, unless that puts more than
            // `resolution` voxels along the longest side; a degenerate box
            // (one point) still gets a grid of some size.
            let finest = (side.max(1e-3) * 1.1) / args.resolution.max(1) as f32;
            if e.pixel > 0.0 && e.pixel.is_finite() {
                (2.0 * e.pixel).max(finest)
            } else {
                finest
            }
        }
    };
    let trunc = args.trunc.unwrap_or(4.0 * voxel);
    let pad: [f32; 3] = std::array::from_fn(|_| 0.05 * side.max(1e-3) + 2.0 * voxel);
    let origin: [f32; 3] = std::array::from_fn(|k| lo[k] - pad[k]);
    let dims_f: [f64; 3] = std::array::from_fn(|k| (((hi[k] + pad[k]) - origin[k]) as f64 / voxel as f64).ceil().max(2.0));
    if dims_f.iter().any(|&d| d > u32::MAX as f64) {
        bail!("voxel {voxel} over a {:?} box gives {:?} voxels per axis: choose a larger --voxel", [0, 1, 2].map(|k| hi[k] - lo[k]), dims_f);
    }
    // Its sizes and rules are checked where it is allocated
    // (TsdfFusion::volume), naming its size in MiB.
    Ok(TsdfGrid { origin, voxel, dims: dims_f.map(|d| d as u32), trunc, depth_max: args.depth_max.unwrap_or(f32::INFINITY) })
}

/// The options against the grid's rules ([`TsdfGrid::validate`]), before
/// any work.
fn check_options(args: &MeshArgs) -> Result<()> {
    if args.voxel.is_none() && args.resolution == 0 {
        bail!("--resolution must be at least 1");
    }
    let probe = TsdfGrid { origin: [0.0; 3], voxel: args.voxel.unwrap_or(1.0), dims: [1; 3], trunc: args.trunc.unwrap_or(1.0), depth_max: args.depth_max.unwrap_or(f32::INFINITY) };
    probe.validate().context("tgs mesh options (--voxel, --trunc, --depth-max)")
}

/// A surface being fused: its volume and its three per-view planes on the
/// device (sized for the largest view, reused).
struct Fusing {
    vol: TsdfVolume,
    planes: [Buffer<f32>; 3],
}

impl Fusing {
    fn new(ctx: &Arc<Context>, fusion: &TsdfFusion, grid: TsdfGrid, args: &MeshArgs, npix: usize, label: &str) -> Result<Fusing> {
        let vol = fusion.volume(grid, args.max_bytes).with_context(|| format!("the {label} mesh's grid"))?;
        let planes = [Buffer::uninit(ctx, "mesh.depth", npix)?, Buffer::uninit(ctx, "mesh.pix_weight", npix)?, Buffer::uninit(ctx, "mesh.colour", 3 * npix)?];
        Ok(Fusing { vol, planes })
    }

    fn record(&self, fusion: &TsdfFusion, rec: &mut Recorder, cam: &Camera, (d, w, c): &Planes) -> Result<()> {
        let [bd, bw, bc] = &self.planes;
        bd.upload(d)?;
        bw.upload(w)?;
        bc.upload(c)?;
        fusion.record(rec, &self.vol, cam, bd, bw, bc)
    }
}

/// `tgs mesh`: write `mesh_scene.ply` and, when the run has a reflection
/// set, `mesh_glass.ply` into `args.out` (default the run directory). Two
/// renders a view: one for the grids' extents, one for the fusion of both
/// surfaces.
pub fn mesh(ctx: &Arc<Context>, run: &Path, args: &MeshArgs) -> Result<Vec<MeshReport>> {
    check_options(args)?;
    let (mut tr, data) = open_run(ctx, run)?;
    let cams: Vec<Camera> = data.train.iter().map(|v| v.camera).collect();
    if cams.is_empty() {
        bail!("{}: the run's dataset has no training views to fuse", data.root.display());
    }
    let out = args.out.clone().unwrap_or_else(|| run.to_path_buf());
    let mut dir = OutDir::open(&out, Some(&data.root))?;
    let _lock = crate::lock::lock_output(&out, run, "tgs mesh", false)?;
    // Refuse before any work if a file is in the way.
    for name in ["mesh_scene.ply", "mesh_glass.ply"] {
        dir.check(name)?;
    }
    let depth_max = args.depth_max.unwrap_or(f32::INFINITY);
    let (scene, glass) = bounds(&mut tr, &cams, depth_max)?;
    let Some(scene) = scene else {
        bail!("{}: no training view sees a surface (within --depth-max): nothing to mesh", run.display());
    };
    let npix = cams.iter().map(|c| c.width as usize * c.height as usize).max().unwrap_or(1);
    let fusion = TsdfFusion::new(ctx)?;
    let mut surfaces = Vec::new();
    for (extent, name, label) in [(Some(scene), "mesh_scene.ply", "scene"), (glass, "mesh_glass.ply", "glass")] {
        let Some(extent) = extent else { continue };
        let grid = grid_for(&extent, args).with_context(|| format!("the {label} mesh's grid"))?;
        if args.progress {
            let [x, y, z] = grid.dims;
            eprintln!(
                "{label}: {x}x{y}x{z} voxels of {:.4} ({:.0} MiB), truncation {:.4}",
                grid.voxel,
                (x as f64 * y as f64 * z as f64 * BYTES_PER_VOXEL as f64) / 1048576.0,
                grid.trunc
            );
        }
        surfaces.push((Fusing::new(ctx, &fusion, grid, args, npix, label)?, name));
    }
    let bar = if args.progress { indicatif::ProgressBar::new(cams.len() as u64).with_message("fusing") } else { indicatif::ProgressBar::hidden() };
    for cam in &cams {
        let (s, g) = view_planes(&mut tr, cam)?;
        let mut rec = Recorder::new(ctx)?;
        surfaces[0].0.record(&fusion, &mut rec, cam, &s)?;
        if let (Some((f, _)), Some(g)) = (surfaces.get(1), &g) {
            f.record(&fusion, &mut rec, cam, g)?;
        }
        rec.submit_and_wait()?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    let mut reports = Vec::new();
    for (f, name) in surfaces {
        let grid = f.vol.grid;
        let mesh = extract(&f.vol.download()?, grid.origin, grid.voxel, 0.0);
        let path = dir.file(name)?;
        ply::write_mesh(&path, &mesh)?;
        reports.push(MeshReport { path, grid, mesh });
    }
    Ok(reports)
}
