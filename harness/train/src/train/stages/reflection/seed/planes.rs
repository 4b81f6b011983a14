//! Planes through the hull's own points ([`SeedParams::planes`]): with
//! given glass masks the hull's first points lie near the glass (`vehicle`
//! at 50²: a median 0.025 off it) but scattered by the masks' pixels and
//! the march's steps, so the plane through a seed's 16 nearest neighbours
//! is some 20 degrees off a flat window's. Where a view's hull points over
//! one piece of its mask lie on one plane, or on two meeting at a corner
//! (the rim's [`Membrane`]), to within [`PLANE_TOL`] of their depth, that
//! piece's seeds are moved onto it along their rays and take its normal;
//! a curved piece (a sphere's silhouette) fits no plane and keeps its seeds.
//! With `most` 3, a piece that neither explains may take three planes at a
//! convex corner ([`Corner3`]: a glass box seen from above shows its top
//! and two sides).

use super::rim::{consensus, corner, fit_plane, inv_at, off_plane, pieces, world_normal, Membrane, NO_PIECE};
use super::{image_point, image_xy, pixel_of, unproject_xy, Found, Prepared, V3};
use glam::DVec3;

/// How far from a piece's plane (a share of the depth) its hull points may
/// lie and count as on it.
pub const PLANE_TOL: f64 = 0.02;
/// The share of a piece's hull points that must lie on its plane(s).
pub const PLANE_SHARE: f64 = 0.8;
/// The fewest hull points a piece's plane is fitted to.
const PLANE_MIN_POINTS: usize = 12;

/// Moves the seeds `found` holds (those not already on a rim membrane)
/// onto their piece's plane where it has one, with its normal; returns how
/// many pieces got a plane.
pub(super) fn snap(found: &mut Found, views: &[Prepared], most: u32) -> usize {
    let mut planes = 0;
    for (vi, v) in views.iter().enumerate() {
        let (w, h) = (v.cam.width as usize, v.cam.height as usize);
        let (piece, n) = pieces(&v.mask, w, h);
        // Per piece: the seeds' indices and their [x, y, 1 / z].
        let mut groups: Vec<Vec<(usize, [f64; 3])>> = vec![Vec::new(); n as usize];
        for (j, &(x, from)) in found.significant.iter().enumerate() {
            if from != vi || found.rim_normals[j].is_some() {
                continue;
            }
            let (Some((i, _)), Some((u, vv, z))) = (pixel_of(&v.cam, x), image_point(&v.cam, x)) else { continue };
            if piece[i] != NO_PIECE {
                let (x, y) = image_xy(&v.cam, u, vv);
                groups[piece[i] as usize].push((j, [x, y, 1.0 / z]));
            }
        }
        for g in groups.iter().filter(|g| g.len() >= PLANE_MIN_POINTS) {
            let pts: Vec<[f64; 3]> = g.iter().map(|p| p.1).collect();
            let Some(m) = piece_surface(&pts, most) else { continue };
            planes += 1;
            // Only the points the plane explains: a curved piece's
            // (`windshield`) others stay where the hull put them.
            for &(j, p) in g.iter().filter(|p| m.off(&p.1) <= PLANE_TOL) {
                if let Some(z) = m.depth_at(&p) {
                    found.significant[j].0 = unproject_xy(&v.cam, p[0], p[1], z);
                    found.rim_normals[j] = Some(m.normal_at(v, &p));
                }
            }
        }
    }
    planes
}

/// The plane, or the corner of two (or, with `most` 3, of three), that
/// [`PLANE_SHARE`] of `pts` ([x, y, 1 / z]) lie on within [`PLANE_TOL`].
fn piece_surface(pts: &[[f64; 3]], most: u32) -> Option<Surface> {
    let holds = |off: &dyn Fn(&[f64; 3]) -> f64| pts.iter().filter(|p| off(p) <= PLANE_TOL).count() as f64 >= PLANE_SHARE * pts.len() as f64;
    let one = Membrane { coef: consensus(pts, PLANE_TOL)?, corner: None };
    let m = corner(pts, one, PLANE_TOL).unwrap_or(one);
    if holds(&|p| m.off(p)) {
        return Some(Surface::Membrane(m));
    }
    let c = if most >= 3 { corner3(pts, PLANE_TOL)? } else { return None };
    (c.distinct() && holds(&|p| c.off(p))).then_some(Surface::Corner3(c))
}

/// What a piece's seeds are moved onto: a [`Membrane`] (one plane or a
/// corner of two) or a [`Corner3`].
enum Surface {
    Membrane(Membrane),
    Corner3(Corner3),
}

impl Surface {
    fn off(&self, p: &[f64; 3]) -> f64 {
        match self {
            Surface::Membrane(m) => m.off(p),
            Surface::Corner3(c) => c.off(p),
        }
    }

    /// The surface's depth along the ray of `p` ([x, y, 1 / z]).
    fn depth_at(&self, p: &[f64; 3]) -> Option<f64> {
        match self {
            Surface::Membrane(m) => m.depth_at(p[0], p[1]),
            Surface::Corner3(c) => {
                let inv = inv_at(c.plane(p), p[0], p[1]);
                (inv > 1e-9 && inv.is_finite()).then(|| 1.0 / inv)
            }
        }
    }

    /// The surface's unit world normal where the ray of `p` meets it.
    fn normal_at(&self, v: &Prepared, p: &[f64; 3]) -> V3 {
        match self {
            Surface::Membrane(m) => m.normal_at(v, p[0], p[1]),
            Surface::Corner3(c) => world_normal(v, c.plane(p)),
        }
    }
}

/// Three planes ([x, y, 1 / z] coefficients), each hull point on the
/// nearest of them (a box's corner: its top and two sides).
#[derive(Clone, Copy, Debug)]
struct Corner3 {
    planes: [[f64; 3]; 3],
}

impl Corner3 {
    /// The plane nearest `p` ([x, y, 1 / z]; the first of equals).
    fn plane(&self, p: &[f64; 3]) -> &[f64; 3] {
        let mut best = &self.planes[0];
        for c in &self.planes[1..] {
            if off_plane(c, p) < off_plane(best, p) {
                best = c;
            }
        }
        best
    }

    fn off(&self, p: &[f64; 3]) -> f64 {
        off_plane(self.plane(p), p)
    }

    /// Whether every two of the planes meet at [`CORNER3_DEGREES`] or
    /// more (a box's faces; a curved piece's three planes lie closer).
    fn distinct(&self) -> bool {
        let n = self.planes.map(|c| DVec3::from(c).normalize_or_zero());
        let cos_max = CORNER3_DEGREES.to_radians().cos();
        [(0, 1), (0, 2), (1, 2)].iter().all(|&(i, j)| n[i].dot(n[j]).abs() <= cos_max)
    }
}

/// The least angle between two planes of a [`Corner3`]: measured on the
/// suite's `dome` at 50², three-plane fits that hold 80% of a piece's
/// points meet at 0–32°, `cabinet`'s box corners at 76–84°
/// (perf/journal/2026-12-06-sixty-fifth.md).
pub const CORNER3_DEGREES: f64 = 45.0;

/// Three planes through `pts` ([x, y, 1 / z]): each a consensus of the
/// points the ones before leave, then each refitted (three rounds) to the
/// points within `tol` that lie nearest it. None where a plane holds
/// fewer than [`PLANE_MIN_POINTS`].
fn corner3(pts: &[[f64; 3]], tol: f64) -> Option<Corner3> {
    let mut planes: Vec<[f64; 3]> = Vec::with_capacity(3);
    let mut rest = pts.to_vec();
    for _ in 0..3 {
        let c = consensus(&rest, tol)?;
        rest.retain(|p| off_plane(&c, p) > tol);
        planes.push(c);
    }
    let mut planes: [[f64; 3]; 3] = [planes[0], planes[1], planes[2]];
    for _ in 0..3 {
        let mut sets: [Vec<[f64; 3]>; 3] = Default::default();
        for p in pts {
            let (k, d) = (0..3).map(|k| (k, off_plane(&planes[k], p))).min_by(|a, b| a.1.total_cmp(&b.1))?;
            if d <= tol {
                sets[k].push(*p);
            }
        }
        if sets.iter().any(|s| s.len() < PLANE_MIN_POINTS) {
            return None;
        }
        planes = [fit_plane(&sets[0])?, fit_plane(&sets[1])?, fit_plane(&sets[2])?];
    }
    Some(Corner3 { planes })
}
