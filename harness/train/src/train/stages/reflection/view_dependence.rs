//! How much of the Stage I residual changes with the view (the Stage II
//! skip decision).
//!
//! The residual's size cannot tell reflections from underfitting: on a
//! path-traced diffuse scene at 50² Stage I leaves a residual as large as on
//! glass scenes (fine textures, the far field). But Stage I is one 3D
//! model: where it misfits a diffuse surface it misfits it the same way from
//! every view, so the residual at that surface point is the same in every
//! view that sees it. A reflection on glass in front of that point changes
//! with the view, and so does the residual. The measure is therefore the
//! spread of the signed residual over the views that see the same Stage I
//! surface point: for a sample pixel with a Stage I depth inside the camera
//! sphere (far-field surfaces are excluded: their depth is a placement, not
//! geometry), each view that sees its surface point unoccluded (its own
//! Stage I depth there within 2% of the point's) gives its residual at the
//! point's pixel. The sample's spread is the residuals' mean absolute
//! deviation from their mean, over the channels; the measure is the median
//! spread over the samples that at least 3 views see (a median, because
//! depth errors at edges and Monte Carlo fireflies give a few samples large
//! spreads on any scene).

use super::seed::{pixel_of, unproject_pixel};
use crate::data::downscale_camera;
use crate::data::image_io::ImageF;
use tgs_pipelines::Camera;

/// One view's residual and depth, reduced so that its longer side is at
/// most `max_side` pixels (memory and time stay bounded at any image size).
pub struct VdMap {
    pub camera: Camera,
    /// Signed residual I_gt - I_scat, 3 planes, box-averaged.
    pub residual: Vec<f32>,
    /// Stage I surface depth (view z) at each block's centre pixel; 0 or
    /// non-finite where there is none.
    pub depth: Vec<f32>,
}

impl VdMap {
    /// From a full-size view: `residual` holds at least 3 planes of
    /// width x height, `depth` one.
    pub fn new(camera: &Camera, residual: &[f32], depth: &[f32], max_side: u32) -> VdMap {
        let (w, h) = (camera.width as usize, camera.height as usize);
        let f = camera.width.max(camera.height).div_ceil(max_side.max(1)).max(1);
        let cam = downscale_camera(camera, f);
        // Box-averaged residual (a side that would round to 0 leaves an empty map).
        let n = w * h;
        let res = ImageF::from_planar(camera.width, camera.height, 3, &residual[..3 * n]).downscale(f).map(|r| r.planar()).unwrap_or_default();
        let (cw, ch, f) = (cam.width as usize, cam.height as usize, f as usize);
        let mut dep = vec![0.0f32; cw * ch];
        for y in 0..ch {
            for x in 0..cw {
                dep[y * cw + x] = depth.get((y * f + f / 2).min(h - 1) * w + (x * f + f / 2).min(w - 1)).copied().unwrap_or(0.0);
            }
        }
        VdMap { camera: cam, residual: res, depth: dep }
    }

    fn pixels(&self) -> usize {
        (self.camera.width * self.camera.height) as usize
    }

    fn depth_at(&self, i: usize) -> Option<f64> {
        let d = self.depth[i];
        (d.is_finite() && d > 0.0).then_some(d as f64)
    }
}

/// The measured view dependence of a residual.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViewDependence {
    /// Median over the samples of the residual's mean absolute deviation
    /// across the views that see the sample's surface point.
    pub spread: f64,
    /// Samples that at least 3 views see (0: nothing to measure, spread 0).
    pub samples: u64,
}

/// The view dependence of the residuals in `views` (see the module
/// documentation), from at most `max_samples` sample pixels spread evenly
/// over the views, at surface points inside `sphere` (centre, radius).
/// Deterministic.
pub fn view_dependence(views: &[VdMap], sphere: ([f32; 3], f32), max_samples: usize) -> ViewDependence {
    let total: usize = views.iter().map(VdMap::pixels).sum();
    if total == 0 || max_samples == 0 {
        return ViewDependence::default();
    }
    let stride = total.div_ceil(max_samples).max(1);
    let (centre, r2) = (sphere.0.map(f64::from), (sphere.1 as f64).powi(2));
    let mut spreads = Vec::new();
    let mut vals: Vec<[f64; 3]> = Vec::with_capacity(views.len());
    let mut k = 0usize;
    for a in views {
        for i in 0..a.pixels() {
            k += 1;
            if !k.is_multiple_of(stride) {
                continue;
            }
            let Some(z) = a.depth_at(i) else { continue };
            let x = unproject_pixel(&a.camera, i, z);
            if (0..3).map(|c| (x[c] - centre[c]).powi(2)).sum::<f64>() >= r2 {
                continue;
            }
            vals.clear();
            for b in views {
                let Some((j, zb)) = pixel_of(&b.camera, x) else { continue };
                let Some(db) = b.depth_at(j) else { continue };
                if (db - zb).abs() <= 0.02 * zb {
                    let n = b.pixels();
                    vals.push([0, 1, 2].map(|c| b.residual[c * n + j] as f64));
                }
            }
            if vals.len() < 3 {
                continue;
            }
            let m = vals.len() as f64;
            let mean = [0, 1, 2].map(|c| vals.iter().map(|v| v[c]).sum::<f64>() / m);
            let mad = vals.iter().map(|v| (0..3).map(|c| (v[c] - mean[c]).abs()).sum::<f64>()).sum::<f64>() / (3.0 * m);
            if mad.is_finite() {
                spreads.push(mad);
            }
        }
    }
    spreads.sort_by(f64::total_cmp);
    ViewDependence { spread: spreads.get(spreads.len() / 2).copied().unwrap_or(0.0), samples: spreads.len() as u64 }
}
