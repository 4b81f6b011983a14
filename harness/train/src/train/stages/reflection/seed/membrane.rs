//! A view's rim membrane (the `rim` module): a plane, two planes at a
//! corner, or a curved membrane (the `curved` module) in the view's
//! normalised image coordinates, with its depth and normal at a pixel.

use super::geometry::{image_xy, normalize, V3};
use super::Prepared;

/// A view's membrane: 1 / z = a x + b y + c at normalised image
/// coordinates x = (u - cx) / fx, y = (v - cy) / fy; or, where a mask
/// piece turns a corner (two windows of a cabin meeting edge to edge), two
/// such planes, the surface at each pixel the farther of the two (a convex
/// corner) or the nearer (a concave one).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Membrane {
    pub(super) coef: [f64; 3],
    pub(super) corner: Option<Corner>,
    /// A curved membrane's quadratic terms (without a corner): 1 / z gains
    /// d x² + e x y + f y² (zero for a plane).
    pub(super) bend: [f64; 3],
}

/// A membrane's second plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Corner {
    pub(super) coef: [f64; 3],
    /// The surface is the farther plane (a corner seen from outside).
    pub(super) convex: bool,
}

/// 1 / z of plane `c` at normalised image point (x, y).
fn inv_at(c: &[f64; 3], x: f64, y: f64) -> f64 {
    c[0] * x + c[1] * y + c[2]
}

/// How far `p` ([x, y, 1 / z]) lies from plane `c`, as a share of its depth.
pub(super) fn off_plane(c: &[f64; 3], p: &[f64; 3]) -> f64 {
    (1.0 - inv_at(c, p[0], p[1]) / p[2]).abs()
}

impl Membrane {
    /// A flat membrane: plane `coef`.
    pub(super) fn flat(coef: [f64; 3]) -> Membrane {
        Membrane { coef, corner: None, bend: [0.0; 3] }
    }

    /// 1 / z of the membrane at normalised image point (x, y).
    fn inv(&self, x: f64, y: f64) -> f64 {
        let b = &self.bend;
        inv_at(self.plane(x, y), x, y) + b[0] * x * x + b[1] * x * y + b[2] * y * y
    }

    /// The plane that holds normalised image point (x, y): the first, or at
    /// a corner the farther (convex) or nearer of the two there.
    fn plane(&self, x: f64, y: f64) -> &[f64; 3] {
        match &self.corner {
            Some(k) if (inv_at(&k.coef, x, y) < inv_at(&self.coef, x, y)) == k.convex => &k.coef,
            _ => &self.coef,
        }
    }

    /// Normalised image coordinates of pixel `i` of `v`'s image.
    fn xy(v: &Prepared, i: usize) -> (f64, f64) {
        let w = v.cam.width as usize;
        image_xy(&v.cam, (i % w) as f64, (i / w) as f64)
    }

    /// The membrane's view depth at pixel `i` of `cam`'s image, if it is in
    /// front of the camera.
    pub(super) fn depth(&self, v: &Prepared, i: usize) -> Option<f64> {
        let (x, y) = Self::xy(v, i);
        self.depth_at(x, y)
    }

    /// The membrane's view depth at normalised image point (x, y), if it is
    /// in front of the camera.
    pub(super) fn depth_at(&self, x: f64, y: f64) -> Option<f64> {
        let inv = self.inv(x, y);
        (inv > 1e-9 && inv.is_finite()).then(|| 1.0 / inv)
    }

    /// The membrane's unit normal in world space at pixel `i`.
    pub(super) fn normal(&self, v: &Prepared, i: usize) -> V3 {
        let (x, y) = Self::xy(v, i);
        self.normal_at(v, x, y)
    }

    /// The membrane's unit normal in world space at normalised image point
    /// (x, y): in view space the surface is G = 0, G = a X + b Y + c Z +
    /// (d X² + e X Y + f Y²) / Z - 1, whose gradient at (x, y) is
    /// (a + 2 d x + e y, b + e x + 2 f y, c - d x² - e x y - f y²).
    pub(super) fn normal_at(&self, v: &Prepared, x: f64, y: f64) -> V3 {
        let (c, [d, e, f]) = (self.plane(x, y), self.bend);
        let g = [c[0] + 2.0 * d * x + e * y, c[1] + e * x + 2.0 * f * y, c[2] - d * x * x - e * x * y - f * y * y];
        let m = &v.cam.world_to_view;
        normalize([0, 1, 2].map(|j| (0..3).map(|r| m[r][j] as f64 * g[r]).sum()))
    }

    /// How far `p` ([x, y, 1 / z]) lies from the membrane, as a share of its depth.
    pub(super) fn off(&self, p: &[f64; 3]) -> f64 {
        (1.0 - self.inv(p[0], p[1]) / p[2]).abs()
    }
}
