//! A flat pane marked by its corners: the same number of clicks, in the
//! same order around the pane, in two or more views. Each corner is the
//! point nearest to its rays (least squares), the pane the polygon of the
//! corners on their plane; a view's mask is the pixels whose ray meets
//! that polygon. Tighter than the visual hull of a few views, which for a
//! flat pane is a wedge through it.

use super::{Outline, Rays};
use glam::{DMat3, DVec3};

pub struct Pane {
    centre: DVec3,
    normal: DVec3,
    /// An orthonormal basis of the plane, and the corners in it.
    axes: (DVec3, DVec3),
    polygon: Vec<(f64, f64)>,
}

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
        Ok(Pane { centre, normal, axes: (u, v), polygon })
    }

    /// Whether the ray `o + t d` (t > 0) meets the pane.
    pub fn hit(&self, o: DVec3, d: DVec3) -> bool {
        let den = self.normal.dot(d);
        if den.abs() < 1e-12 {
            return false;
        }
        let t = self.normal.dot(self.centre - o) / den;
        if t <= 0.0 {
            return false;
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
        inside
    }
}
