//! f64 reference of TSDF fusion (`glsl/mesh/tsdf_fuse.comp`): the same
//! update in double precision, and for each voxel whether its outcome
//! could differ in f32 (its projection within `EPS_PX` of a pixel border or
//! of the image edge, its depth test or truncation test within `EPS_Z`):
//! such voxels are left out of comparisons.

use tgs_pipelines::{Camera, HostTsdf, TsdfGrid};

pub const EPS_PX: f64 = 1e-4;
pub const EPS_Z: f64 = 1e-4;

/// One view's inputs: depth and weight per pixel, colour as three planes.
pub struct RefView<'a> {
    pub camera: Camera,
    pub depth: &'a [f32],
    pub weight: &'a [f32],
    pub colour: &'a [f32],
}

/// The fused grid in f64 and the voxels whose f32 outcome may differ.
pub struct RefTsdf {
    pub tsdf: Vec<f64>,
    pub weight: Vec<f64>,
    pub rgb: [Vec<f64>; 3],
    pub ambiguous: Vec<bool>,
}

pub fn fuse(grid: &TsdfGrid, views: &[RefView]) -> RefTsdf {
    let [nx, ny, nz] = grid.dims.map(|d| d as usize);
    let n = nx * ny * nz;
    let mut r = RefTsdf { tsdf: vec![0.0; n], weight: vec![0.0; n], rgb: [vec![0.0; n], vec![0.0; n], vec![0.0; n]], ambiguous: vec![false; n] };
    let trunc = grid.trunc as f64;
    for v in views {
        let c = &v.camera;
        let m = c.world_to_view.map(|row| row.map(f64::from));
        let (w, h) = (c.width as usize, c.height as usize);
        let npix = w * h;
        for idx in 0..n {
            let (i, j, k) = (idx % nx, (idx / nx) % ny, idx / (nx * ny));
            let p = [i, j, k].iter().zip(grid.origin).map(|(&a, o)| o as f64 + (a as f64 + 0.5) * grid.voxel as f64).collect::<Vec<f64>>();
            let q: [f64; 3] = std::array::from_fn(|r| m[r][0] * p[0] + m[r][1] * p[1] + m[r][2] * p[2] + m[r][3]);
            let z = q[2];
            if z.abs() < 1e-4 {
                r.ambiguous[idx] = true;
            }
            if z <= 1e-6 {
                continue;
            }
            let u = c.fx as f64 * q[0] / z + c.cx as f64;
            let y = c.fy as f64 * q[1] / z + c.cy as f64;
            let near_border = |t: f64, size: usize| (t + 0.5 - (t + 0.5).round()).abs() < EPS_PX || (t + 0.5).abs() < EPS_PX || (t + 0.5 - size as f64).abs() < EPS_PX;
            if near_border(u, w) || near_border(y, h) {
                r.ambiguous[idx] = true;
            }
            if !(u >= -0.5 && u < w as f64 - 0.5 && y >= -0.5 && y < h as f64 - 0.5) {
                continue;
            }
            let pix = ((y + 0.5).floor() as usize).min(h - 1) * w + ((u + 0.5).floor() as usize).min(w - 1);
            let (d, wt) = (v.depth[pix] as f64, v.weight[pix] as f64);
            if (d - grid.depth_max as f64).abs() < EPS_Z {
                r.ambiguous[idx] = true;
            }
            if !(d > 0.0 && d <= grid.depth_max as f64 && d.is_finite() && wt > 0.0) {
                continue;
            }
            let sdf = d - z;
            if (sdf + trunc).abs() < EPS_Z {
                r.ambiguous[idx] = true;
            }
            if sdf < -trunc {
                continue;
            }
            let t = (sdf / trunc).min(1.0);
            let (w0, w1) = (r.weight[idx], r.weight[idx] + wt);
            r.tsdf[idx] = (r.tsdf[idx] * w0 + t * wt) / w1;
            for ch in 0..3 {
                r.rgb[ch][idx] = (r.rgb[ch][idx] * w0 + v.colour[ch * npix + pix] as f64 * wt) / w1;
            }
            r.weight[idx] = w1;
        }
    }
    r
}

/// Largest differences (TSDF, weight, colour) between `gpu` and `r` over
/// the voxels not marked ambiguous, and how many were compared.
pub fn compare(gpu: &HostTsdf, r: &RefTsdf) -> (f64, f64, f64, usize) {
    let mut worst = (0.0f64, 0.0f64, 0.0f64, 0usize);
    for i in 0..r.tsdf.len() {
        if r.ambiguous[i] {
            continue;
        }
        worst.0 = worst.0.max((gpu.tsdf[i] as f64 - r.tsdf[i]).abs());
        worst.1 = worst.1.max((gpu.weight[i] as f64 - r.weight[i]).abs());
        for c in 0..3 {
            worst.2 = worst.2.max((gpu.rgb[c][i] as f64 - r.rgb[c][i]).abs());
        }
        worst.3 += 1;
    }
    worst
}
