//! Planes through the hull's own points ([`SeedParams::planes`]): with
//! given glass masks the hull's first points lie near the glass (`vehicle`
//! at 50²: a median 0.025 off it) but scattered by the masks' pixels and
//! the march's steps, so the plane through a seed's 16 nearest neighbours
//! is some 20 degrees off a flat window's. Where a view's hull points over
//! one piece of its mask lie on one plane, or on two meeting at a corner
//! (the rim's [`Membrane`]), to within [`PLANE_TOL`] of their depth, that
//! piece's seeds are moved onto it along their rays and take its normal;
//! a curved piece (a sphere's silhouette) fits no plane and keeps its seeds.

use super::membrane::Membrane;
use super::rim::{consensus, corner, pieces, NO_PIECE};
use super::{image_point, image_xy, pixel_of, unproject_xy, Found, Prepared};

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
pub(super) fn snap(found: &mut Found, views: &[Prepared]) -> usize {
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
            let Some(m) = piece_plane(&pts) else { continue };
            planes += 1;
            // Only the points the plane explains: a curved piece's
            // (`windshield`) others stay where the hull put them.
            for &(j, [x, y, _]) in g.iter().filter(|p| m.off(&p.1) <= PLANE_TOL) {
                if let Some(z) = m.depth_at(x, y) {
                    found.significant[j].0 = unproject_xy(&v.cam, x, y, z);
                    found.rim_normals[j] = Some(m.normal_at(v, x, y));
                }
            }
        }
    }
    planes
}

/// The plane, or the corner of two, that [`PLANE_SHARE`] of `pts`
/// ([x, y, 1 / z]) lie on within [`PLANE_TOL`].
fn piece_plane(pts: &[[f64; 3]]) -> Option<Membrane> {
    let one = Membrane::flat(consensus(pts, PLANE_TOL)?);
    let m = corner(pts, one, PLANE_TOL).unwrap_or(one);
    let on = pts.iter().filter(|p| m.off(p) <= PLANE_TOL).count();
    (on as f64 >= PLANE_SHARE * pts.len() as f64).then_some(m)
}
