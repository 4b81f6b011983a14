//! Flat faces of the glass ([`SeedParams::faces`]): with exact masks the
//! hull's seeds lie within a pixel or two of the glass, but in a shape the
//! masks cannot settle: a box's faces bulge into pillows whose rims round
//! its edges, a free-standing pane's hull is a slab whose top seeds a
//! ridge. There a seed's local plane leans off the glass even after
//! smoothing (`cabinet` at 50²: 47° within 0.05 of an edge, 3° mid-face).
//! Where a large share of the seeds ([`FACE_SHARE`]) lie within a band of
//! one plane with normals within [`FACE_DEGREES`] of it, that plane is a
//! face of the glass, refitted to the seeds it takes: those within the band
//! over its extent whose normal turns at most [`FACE_TURN_DEGREES`] to it,
//! each to the face it stands farthest out of (a box's edge). A curved
//! surface offers no such plane (a sphere's cap within 10° holds about 1%
//! of its seeds, and the seeds a cap would take turn to it by more than
//! [`FACE_MEDIAN_TURN_DEGREES`] at the median) and keeps its normals.
//! perf/journal/2026-12-06-sixty-sixth.md.

use super::{image_point, least_squares_plane, Prepared, Seed, V3};
use glam::{DVec2, DVec3};
use std::collections::HashMap;

/// The band a face's seeds lie in, in pixels at the seeds' depth (the
/// masks' hull is carved to about a pixel; a box's pillows stand 1.5 high).
pub const FACE_BAND_PIXELS: f64 = 1.5;
/// The most a seed's normal may turn from a face's to count towards finding it.
pub const FACE_DEGREES: f64 = 10.0;
/// The share of the seeds a face must hold.
pub const FACE_SHARE: f64 = 0.03;
/// The most a seed's normal may turn to the face that takes it.
pub const FACE_TURN_DEGREES: f64 = 60.0;
/// The most the seeds a face would take may turn to it, at the median:
/// over a face their normals mostly agree with it (a box's 4–9.5° at 50²,
/// its edges' seeds the rest), over a sphere's cap or a cylinder's strip
/// they spread with its curvature (11–22°; an open glass tube's strips
/// 10–12°, which 12° let through: `cylinder` 36.5° → 41.4°).
pub const FACE_MEDIAN_TURN_DEGREES: f64 = 10.0;
/// A face within this angle of one found before and within two bands of
/// its plane is the same face (its rest, the part that leaned more).
const FACE_MERGE_DEGREES: f64 = 20.0;
/// Planes tried per face, each from one seed, refined [`FACE_REFINE`] times.
const FACE_TRIES: usize = 300;
const FACE_REFINE: usize = 3;

/// A face: its plane and where on it its seeds lie.
struct Face {
    centre: DVec3,
    normal: DVec3,
    axes: (DVec3, DVec3),
    /// Its seeds' positions in the plane, by cell of `cell` size.
    cells: HashMap<(i64, i64), Vec<DVec2>>,
    cell: f64,
}

impl Face {
    fn new(centre: DVec3, normal: DVec3, on: impl Iterator<Item = DVec3>, cell: f64) -> Face {
        let axes = normal.any_orthonormal_pair();
        let mut f = Face { centre, normal, axes, cells: HashMap::new(), cell };
        for x in on {
            let q = f.in_plane(x);
            f.cells.entry(f.key(q)).or_default().push(q);
        }
        f
    }

    fn in_plane(&self, x: DVec3) -> DVec2 {
        let d = x - self.centre;
        DVec2::new(d.dot(self.axes.0), d.dot(self.axes.1))
    }

    fn key(&self, q: DVec2) -> (i64, i64) {
        ((q.x / self.cell).floor() as i64, (q.y / self.cell).floor() as i64)
    }

    /// Whether `x` lies over the face: within a cell's size of one of its seeds, along the plane.
    fn over(&self, x: DVec3) -> bool {
        let q = self.in_plane(x);
        let (i, j) = self.key(q);
        (-1..=1).any(|a| (-1..=1).any(|b| self.cells.get(&(i + a, j + b)).is_some_and(|v| v.iter().any(|p| p.distance(q) <= self.cell))))
    }

    /// How far out of the face a seed at `x` with normal `n` stands (along
    /// the face's normal turned to `n`), if the face may take it.
    fn takes(&self, x: DVec3, n: DVec3, band: f64) -> Option<f64> {
        let c = n.dot(self.normal);
        let out = (x - self.centre).dot(self.normal) * if c < 0.0 { -1.0 } else { 1.0 };
        (out.abs() <= 1.5 * band && c.abs() >= FACE_TURN_DEGREES.to_radians().cos() && self.over(x)).then_some(out)
    }
}

/// [`FACE_BAND_PIXELS`] in world units: that many pixels at the median
/// depth of the `found` points in the views that found them.
pub(super) fn face_band(found: &[(V3, usize)], views: &[Prepared]) -> f64 {
    let mut sizes: Vec<f64> = found.iter().filter_map(|&(x, vi)| image_point(&views[vi].cam, x).map(|(_, _, z)| z / views[vi].cam.fx as f64)).collect();
    if sizes.is_empty() {
        return 0.0;
    }
    sizes.sort_by(f64::total_cmp);
    FACE_BAND_PIXELS * sizes[sizes.len() / 2]
}

/// Gives the seeds over a flat face of the glass that face's normal (each
/// turned to the side it faced); `band` is [`FACE_BAND_PIXELS`] in world
/// units. Returns the faces and the seeds they took. Deterministic.
pub fn flat_faces(seeds: &mut [Seed], band: f64) -> (usize, usize) {
    let pos: Vec<DVec3> = seeds.iter().map(|s| DVec3::from(s.position.map(f64::from))).collect();
    let n: Vec<DVec3> = seeds.iter().map(|s| DVec3::from(s.normal.map(f64::from)).normalize_or_zero()).collect();
    let min_support = ((FACE_SHARE * seeds.len() as f64).ceil() as usize).max(3);
    if !(band > 0.0 && band.is_finite()) || seeds.len() < min_support {
        return (0, 0);
    }
    let found = find_faces(&pos, &n, band, min_support);
    // Refit each face to the seeds it takes, over all of them; its extent
    // is where those and the seeds that found it lie.
    let owner = assign(found.iter().map(|f| &f.0), &pos, &n, band);
    let faces: Vec<Face> = found
        .iter()
        .enumerate()
        .filter_map(|(k, (f, support))| {
            let mine: Vec<DVec3> = (0..pos.len()).filter(|&j| owner[j] == Some(k)).map(|j| pos[j]).collect();
            let (centre, normal) = plane_of(&mine, f.normal)?;
            Some(Face::new(centre, normal, support.iter().map(|&j| pos[j]).chain(mine.iter().copied()), f.cell))
        })
        .collect();
    let owner = assign(&faces, &pos, &n, band);
    let mut taken = 0;
    for (s, (o, &old)) in seeds.iter_mut().zip(owner.iter().zip(&n)) {
        if let Some(k) = *o {
            let m = faces[k].normal;
            s.normal = (if m.dot(old) < 0.0 { -m } else { m }).as_vec3().to_array();
            taken += 1;
        }
    }
    (faces.len(), taken)
}

/// The faces, largest first, each with the seeds that found it (its
/// inliers): each the plane (through a seed, refined to the mean of its
/// inliers) that the most of the seeds not yet taken lie on; a face then
/// removes from the pool the seeds it would take.
fn find_faces(pos: &[DVec3], n: &[DVec3], band: f64, min_support: usize) -> Vec<(Face, Vec<usize>)> {
    let cos_in = FACE_DEGREES.to_radians().cos();
    let inlier = |j: usize, c: DVec3, m: DVec3| (pos[j] - c).dot(m).abs() <= band && n[j].dot(m).abs() >= cos_in;
    let mut free = vec![true; pos.len()];
    let mut faces: Vec<(Face, Vec<usize>)> = Vec::new();
    loop {
        let pool: Vec<usize> = (0..pos.len()).filter(|&j| free[j]).collect();
        if pool.len() < min_support {
            break;
        }
        let mut best: Option<(usize, DVec3, DVec3)> = None;
        for t in 0..FACE_TRIES {
            let i = pool[(t * 7919) % pool.len()];
            let (mut c, mut m) = (pos[i], n[i]);
            for _ in 0..FACE_REFINE {
                let (mut sc, mut sm, mut k) = (DVec3::ZERO, DVec3::ZERO, 0usize);
                for &j in pool.iter().filter(|&&j| inlier(j, c, m)) {
                    sc += pos[j];
                    sm += if n[j].dot(m) < 0.0 { -n[j] } else { n[j] };
                    k += 1;
                }
                let Some(mm) = sm.try_normalize().filter(|_| k >= 3) else { break };
                (c, m) = (sc / k as f64, mm);
            }
            let count = pool.iter().filter(|&&j| inlier(j, c, m)).count();
            if best.is_none_or(|(b, _, _)| count > b) {
                best = Some((count, c, m));
            }
        }
        let Some((_, c, m)) = best.filter(|b| b.0 >= min_support) else { break };
        let support: Vec<usize> = pool.iter().copied().filter(|&j| inlier(j, c, m)).collect();
        support.iter().for_each(|&j| free[j] = false);
        let merge = FACE_MERGE_DEGREES.to_radians().cos();
        if faces.iter().any(|(f, _)| m.dot(f.normal).abs() >= merge && (c - f.centre).dot(f.normal).abs() <= 2.0 * band) {
            continue;
        }
        let face = Face::new(c, m, support.iter().map(|&j| pos[j]), 3.0 * band);
        let taken: Vec<usize> = (0..pos.len()).filter(|&j| face.takes(pos[j], n[j], band).is_some()).collect();
        let mut turns: Vec<f64> = taken.iter().map(|&j| n[j].dot(m).abs().min(1.0).acos().to_degrees()).collect();
        turns.sort_by(f64::total_cmp);
        if turns.get(turns.len() / 2).is_none_or(|&t| t > FACE_MEDIAN_TURN_DEGREES) {
            continue;
        }
        taken.iter().for_each(|&j| free[j] = false);
        faces.push((face, support));
    }
    faces
}

/// Per seed, the face that takes it and that it stands farthest out of.
fn assign<'a>(faces: impl IntoIterator<Item = &'a Face> + Clone, pos: &[DVec3], n: &[DVec3], band: f64) -> Vec<Option<usize>> {
    (0..pos.len())
        .map(|j| {
            let mut best: Option<(f64, usize)> = None;
            for (k, f) in faces.clone().into_iter().enumerate() {
                if let Some(out) = f.takes(pos[j], n[j], band) {
                    if best.is_none_or(|(b, _)| out > b) {
                        best = Some((out, k));
                    }
                }
            }
            best.map(|b| b.1)
        })
        .collect()
}

/// The least-squares plane (centre, unit normal turned to `towards`) of `pts`; None for fewer than 3.
fn plane_of(pts: &[DVec3], towards: DVec3) -> Option<(DVec3, DVec3)> {
    if pts.len() < 3 {
        return None;
    }
    let (c, m) = least_squares_plane(pts);
    let m = m.try_normalize()?;
    Some((c, if m.dot(towards) < 0.0 { -m } else { m }))
}
