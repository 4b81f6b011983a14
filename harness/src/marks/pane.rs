//! A flat pane marked by its corners: the same number of clicks, in the
//! same order around the pane, in two or more views. Each corner is the
//! point nearest to its rays (least squares), the pane the polygon of the
//! corners on their plane; a view's mask is the pixels whose ray meets
//! that polygon. Tighter than the visual hull of a few views, which for a
//! flat pane is a wedge through it.

use super::{Outline, Rays};
use crate::train::stages::reflection::seed::PanePolygon;
use glam::{DMat3, DVec3};

pub struct Pane(pub PanePolygon);

impl Pane {
    /// The pane of `outlines` (those of three clicks or more), or why
    /// there is none: fewer than two views, different click counts, or
    /// corners whose rays do not meet (more than `tolerance_px` from a
    /// click when projected back) or do not lie on a plane.
    pub fn triangulate(outlines: &[Outline]) -> Result<Pane, String> {
        let outs: Vec<&Outline> = outlines.iter().filter(|o| o.points.len() >= 3).collect();
        if outs.len() < 2 {
            return Err(format!("a pane needs its corners in two views or more ({} so far)", outs.len()));
        }
        let n = outs[0].points.len();
        if outs.iter().any(|o| o.points.len() != n) {
            let counts: Vec<String> = outs.iter().map(|o| o.points.len().to_string()).collect();
            return Err(format!("a pane's views need the same number of corners ({})", counts.join(", ")));
        }
        let rays: Vec<Rays> = outs.iter().map(|o| Rays::of(&o.camera)).collect();
        let mut corners = Vec::with_capacity(n);
        for k in 0..n {
            let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
            for (o, r) in outs.iter().zip(&rays) {
                let d = r.dir(o.points[k].0, o.points[k].1).normalize();
                // (I - d d^T): the part of a point's offset across the ray.
                let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
                a += m;
                b += m * r.centre;
            }
            if a.determinant().abs() < 1e-12 {
                return Err(format!("corner {}: its rays are parallel (views too close together)", k + 1));
            }
            corners.push(a.inverse() * b);
        }
        for (o, r) in outs.iter().zip(&rays) {
            let tolerance_px = (0.02 * o.camera.width.max(o.camera.height) as f64).max(2.0);
            for (k, (&c, &(u, v))) in corners.iter().zip(&o.points).enumerate() {
                match r.project(c) {
                    Some((pu, pv)) if (pu - u).hypot(pv - v) <= tolerance_px => {}
                    _ => return Err(format!("corner {}: its clicks do not meet in 3D (click the corners in the same order in each view)", k + 1)),
                }
            }
        }
        PanePolygon::from_corners(&corners).map(Pane)
    }

    /// Whether the ray `o + t d` (t > 0) meets the pane.
    pub fn hit(&self, o: DVec3, d: DVec3) -> bool {
        self.0.hit(o, d).is_some()
    }
}
