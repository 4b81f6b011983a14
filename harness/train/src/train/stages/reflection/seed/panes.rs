//! Seeds on the flat panes a user marked in `tgs view` by their corners
//! (key F; `marks.json`'s `pane` corners): the marks carry the glass's
//! plane, so the seeds lie on it with its normal, where the masks' hull
//! (the hull of one pane's projections) and a rim plane fitted to what
//! rings it only approximate it. A vehicle's four windows marked so at
//! 50²: the hull's seeds 65–90° off the windows, the marked panes 2–8°
//! (perf/journal/2026-12-07-sixty-seventh.md).

use super::geometry::{in_parallel, unproject_pixel, V3};
use super::normals::surfels;
use super::{strided_rays, Prepared, Seed, SeedParams, SeedView};
use glam::DVec3;

/// A pane's hit this far behind the view's Stage I depth is hidden there.
const HIDDEN: f64 = 1.02;

/// A flat polygon in 3D: its corners' plane and their outline in it.
#[derive(Clone, Debug, PartialEq)]
pub struct PanePolygon {
    centre: DVec3,
    normal: DVec3,
    /// An orthonormal basis of the plane, and the corners in it.
    axes: (DVec3, DVec3),
    polygon: Vec<(f64, f64)>,
}

impl PanePolygon {
    /// The polygon of `corners` (in order around it) on their plane, or
    /// why there is none: fewer than three, on a line, or a corner farther
    /// from the plane than a tenth of the pane's size.
    pub fn from_corners(corners: &[DVec3]) -> Result<PanePolygon, String> {
        let n = corners.len();
        if n < 3 || corners.iter().any(|c| !c.is_finite()) {
            return Err(format!("a pane needs three corners or more, all finite ({n} given)"));
        }
        let centre = corners.iter().copied().sum::<DVec3>() / n as f64;
        // Newell's normal: the polygon's area vector, robust to noise in the corners.
        let area: DVec3 = (0..n).map(|i| corners[i].cross(corners[(i + 1) % n])).sum();
        let size = corners.iter().map(|c| (*c - centre).length()).fold(0.0, f64::max);
        if area.length() < 1e-9 * size.max(1e-9) {
            return Err("the corners lie on a line".into());
        }
        let normal = area.normalize();
        if corners.iter().any(|c| (*c - centre).dot(normal).abs() > 0.1 * size) {
            return Err("the corners do not lie on a plane".into());
        }
        let u = (corners[0] - centre).reject_from(normal).normalize();
        let v = normal.cross(u);
        let polygon = corners.iter().map(|c| ((*c - centre).dot(u), (*c - centre).dot(v))).collect();
        Ok(PanePolygon { centre, normal, axes: (u, v), polygon })
    }

    /// The unit normal (the corners counter-clockwise about it).
    pub fn normal(&self) -> DVec3 {
        self.normal
    }

    /// The corners, on the plane.
    pub fn corners(&self) -> Vec<DVec3> {
        self.polygon.iter().map(|&(x, y)| self.centre + x * self.axes.0 + y * self.axes.1).collect()
    }

    /// Where the ray `o + t d` (t > 0) meets the polygon: its t.
    pub fn hit(&self, o: DVec3, d: DVec3) -> Option<f64> {
        let den = self.normal.dot(d);
        if den.abs() < 1e-12 {
            return None;
        }
        let t = self.normal.dot(self.centre - o) / den;
        if t <= 0.0 {
            return None;
        }
        let p = o + t * d - self.centre;
        let (x, y) = (p.dot(self.axes.0), p.dot(self.axes.1));
        // Crossing number: the polygon need not be convex.
        let n = self.polygon.len();
        let mut inside = false;
        for i in 0..n {
            let (a, b) = (self.polygon[i], self.polygon[(i + 1) % n]);
            if (a.1 > y) != (b.1 > y) && x < a.0 + (y - a.1) / (b.1 - a.1) * (b.0 - a.0) {
                inside = !inside;
            }
        }
        inside.then_some(t)
    }
}

/// The seeds on `panes`: the masked pixels' rays (every `stride`-th over
/// the views, at most [`SeedParams::max_rays`], as the hull's march takes
/// them) each seed where it first meets a pane, with the pane's normal
/// turned to its camera and the hull seeds' size (the spacing to their
/// nearest neighbours). A ray that meets no pane, or meets it behind the
/// view's Stage I surface (hidden there), seeds nothing.
/// Deterministic, the same at any thread count.
pub fn pane_seeds(views: &[SeedView], panes: &[PanePolygon], p: &SeedParams) -> Vec<Seed> {
    let prepared: Vec<Prepared> = views.iter().map(|v| Prepared::new(v, p)).collect();
    let total: usize = prepared.iter().map(|v| v.mask.iter().filter(|&&m| m).count()).sum();
    if total == 0 || panes.is_empty() {
        return Vec::new();
    }
    let rays = strided_rays(&prepared, total, p.max_rays);
    let hits: Vec<(V3, usize, V3)> = in_parallel(&rays, p.threads, |run| {
        run.iter()
            .filter_map(|&(vi, i)| {
                let cam = &prepared[vi].cam;
                let o = DVec3::from(cam.centre().map(f64::from));
                let d = DVec3::from(unproject_pixel(cam, i, 1.0)) - o;
                let (t, pane) = panes.iter().filter_map(|q| q.hit(o, d).map(|t| (t, q))).min_by(|a, b| a.0.total_cmp(&b.0))?;
                // Behind the Stage I surface (d has view depth 1, so t is
                // the hit's): an opaque thing hides the pane in this view,
                // which the marks do not model.
                (t <= prepared[vi].depth[i] as f64 * HIDDEN).then(|| ((o + t * d).to_array(), vi, pane.normal.to_array()))
            })
            .collect::<Vec<_>>()
    })
    .concat();
    let found: Vec<(V3, usize)> = hits.iter().map(|&(x, vi, _)| (x, vi)).collect();
    let fixed: Vec<Option<V3>> = hits.iter().map(|&(_, _, n)| Some(n)).collect();
    surfels(&found, &fixed, &prepared, p.normal, p.threads)
}
