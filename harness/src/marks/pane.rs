//! A flat pane marked by its corners: the same number of clicks, in
//! order around the pane (starting anywhere, either way round: each view
//! is matched to the first), in two or more views. Each corner is the
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
        // Each later view's clicks in the first view's order: started at
        // any corner and going either way round, the turn whose rays pass
        // closest to the first view's (a user need not keep the order).
        let mut points: Vec<Vec<(f64, f64)>> = vec![outs[0].points.clone()];
        for (o, r) in outs.iter().zip(&rays).skip(1) {
            let turns = (0..2 * n).map(|t| (0..n).map(|k| o.points[if t < n { (t + k) % n } else { (t + n - k) % n }]).collect::<Vec<_>>());
            let misfit = |p: &Vec<(f64, f64)>| corners_of(&[&rays[0], r], &[&points[0], p]).map_or(f64::INFINITY, |c| reprojection(&[&rays[0], r], &[&points[0], p], &c));
            // The first of the best (the clicks' own order on a tie).
            let best = turns.map(|p| (misfit(&p), p)).min_by(|a, b| a.0.total_cmp(&b.0));
            points.push(best.map_or_else(|| o.points.clone(), |(_, p)| p));
        }
        let ray_refs: Vec<&Rays> = rays.iter().collect();
        let point_refs: Vec<&Vec<(f64, f64)>> = points.iter().collect();
        let corners = corners_of(&ray_refs, &point_refs)?;
        for ((o, r), p) in outs.iter().zip(&rays).zip(&points) {
            let tolerance_px = (0.02 * o.camera.width.max(o.camera.height) as f64).max(2.0);
            for (k, (&c, &(u, v))) in corners.iter().zip(p).enumerate() {
                match r.project(c) {
                    Some((pu, pv)) if (pu - u).hypot(pv - v) <= tolerance_px => {}
                    _ => return Err(format!("corner {}: its clicks do not meet in 3D (click the same corners in each view)", k + 1)),
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

/// Each corner the point nearest its clicks' rays (least squares), one
/// click per view in `points` (the same order in each); or why not.
fn corners_of(rays: &[&Rays], points: &[&Vec<(f64, f64)>]) -> Result<Vec<DVec3>, String> {
    (0..points[0].len())
        .map(|k| {
            let (mut a, mut b) = (DMat3::ZERO, DVec3::ZERO);
            for (r, p) in rays.iter().zip(points) {
                let d = r.dir(p[k].0, p[k].1).normalize();
                // (I - d d^T): the part of a point's offset across the ray.
                let m = DMat3::IDENTITY - DMat3::from_cols(d * d.x, d * d.y, d * d.z);
                a += m;
                b += m * r.centre;
            }
            if a.determinant().abs() < 1e-12 {
                return Err(format!("corner {}: its rays are parallel (views too close together)", k + 1));
            }
            Ok(a.inverse() * b)
        })
        .collect()
}

/// The largest distance (pixels) between a click and its corner's
/// projection; infinite where a corner is behind a camera.
fn reprojection(rays: &[&Rays], points: &[&Vec<(f64, f64)>], corners: &[DVec3]) -> f64 {
    let mut worst = 0.0f64;
    for (r, p) in rays.iter().zip(points) {
        for (&c, &(u, v)) in corners.iter().zip(p.iter()) {
            worst = worst.max(r.project(c).map_or(f64::INFINITY, |(pu, pv)| (pu - u).hypot(pv - v)));
        }
    }
    worst
}
