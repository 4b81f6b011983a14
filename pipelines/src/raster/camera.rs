//! Pinhole cameras in the rasterizer's convention: OpenCV axes (x right,
//! y down, z forward), pixel centres at integer coordinates (pixel (i, j) is
//! at x = i, y = j), per-camera fx, fy, cx, cy and size. Loaders convert other
//! conventions (COLMAP's half-pixel principal point, Blender's OpenGL axes)
//! into this one at load time.

use anyhow::{bail, Result};
use glam::{DVec3, Vec3};

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// World -> view transform, rows of (R | t): p_view = R p + t.
    pub world_to_view: [[f32; 4]; 3],
}

/// `v` over its length (divided, not multiplied by the reciprocal: the
/// cameras of datasets made before glam keep their bits).
fn unit(v: DVec3) -> DVec3 {
    v / v.length()
}

impl Camera {
    /// A camera at `eye` looking at `target`, `up` pointing up in the image,
    /// vertical field of view `fov_y` (radians), principal point at the image centre.
    pub fn look_at(eye: [f32; 3], target: [f32; 3], up: [f32; 3], fov_y: f32, width: u32, height: u32) -> Camera {
        let e = Vec3::from(eye).as_dvec3();
        let z = unit(Vec3::from(target).as_dvec3() - e);
        let x = unit(z.cross(Vec3::from(up).as_dvec3()));
        let y = z.cross(x);
        let f = 0.5 * height as f64 / (0.5 * fov_y as f64).tan();
        let row = |r: DVec3| [r.x as f32, r.y as f32, r.z as f32, -r.dot(e) as f32];
        Camera { width, height, fx: f as f32, fy: f as f32, cx: (width as f32 - 1.0) * 0.5, cy: (height as f32 - 1.0) * 0.5, world_to_view: [row(x), row(y), row(z)] }
    }

    /// Camera centre in world space: -R^T t.
    pub fn centre(&self) -> [f32; 3] {
        let m = &self.world_to_view;
        let mut c = [0.0f32; 3];
        for (j, cj) in c.iter_mut().enumerate() {
            *cj = -(0..3).map(|i| m[i][j] * m[i][3]).sum::<f32>();
        }
        c
    }

    /// The world point at pixel coordinates (u, v) and view depth z:
    /// R^T (p_view - t).
    pub fn unproject(&self, u: f32, v: f32, z: f32) -> [f32; 3] {
        let m = &self.world_to_view;
        let p = [(u - self.cx) / self.fx * z, (v - self.cy) / self.fy * z, z];
        let d = [p[0] - m[0][3], p[1] - m[1][3], p[2] - m[2][3]];
        [0, 1, 2].map(|j| (0..3).map(|i| m[i][j] * d[i]).sum())
    }

    pub fn validate(&self) -> Result<()> {
        let finite = [self.fx, self.fy, self.cx, self.cy].iter().chain(self.world_to_view.iter().flatten()).all(|v| v.is_finite());
        if !finite {
            bail!("camera has a non-finite intrinsic or pose value: {self:?}");
        }
        if !(self.fx > 0.0 && self.fy > 0.0) {
            bail!("camera focal lengths must be positive (fx {}, fy {})", self.fx, self.fy);
        }
        if self.width == 0 || self.height == 0 {
            bail!("camera image size {}x{} is empty", self.width, self.height);
        }
        Ok(())
    }

    /// The camera block of the rasterizer kernels (see glsl/raster/common.glsl).
    pub(crate) fn pack(&self, background: &[f32]) -> Vec<f32> {
        let mut v = Vec::with_capacity(20 + background.len());
        for r in &self.world_to_view {
            v.extend_from_slice(r);
        }
        v.extend_from_slice(&[self.fx, self.fy, self.cx, self.cy]);
        v.extend_from_slice(&self.centre());
        v.push(0.0);
        v.extend_from_slice(background);
        v
    }
}
